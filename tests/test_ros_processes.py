"""Two separate processes exchange EnvObservation messages over a real Fast DDS topic."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HELPERS = Path(__file__).parent / "ros_helpers"


def test_two_processes_exchange_observations(ros_domain):
    n = 50
    topic = "/nmrm/test/observations"
    env = os.environ.copy()
    sub = subprocess.Popen([sys.executable, str(HELPERS / "observation_subscriber.py"), topic, str(n)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    pub = subprocess.Popen([sys.executable, str(HELPERS / "observation_publisher.py"), topic, str(n)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        sub_out, sub_err = sub.communicate(timeout=60)
        pub_out, pub_err = pub.communicate(timeout=60)
    finally:
        for p in (sub, pub):
            if p.poll() is None:
                p.kill()
    assert sub.returncode == 0, sub_err
    assert pub.returncode == 0, pub_err
    got = [json.loads(line) for line in sub_out.splitlines()]
    assert [m["step"] for m in got] == list(range(n))
    assert all(m["task"] == "key" and m["episode"] == 7 for m in got)
    assert got[10]["state"] == [np.float32(0.1).item(), np.float32(0.9).item()]
    assert [m["truncated"] for m in got] == [False] * (n - 1) + [True]
