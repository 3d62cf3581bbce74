"""Fault injection with real processes: what a hostile user or a crash does to the graph."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from graph_helpers import finish, launch


def _children(pid: int) -> list:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "State:\tZ" not in state  # a zombie has ended


def _started_graph() -> tuple:
    """`nmrm launch` of a graph that runs for ever, once its nodes are up; (process, node pids)."""
    proc = launch("episodes:=0")
    seen, deadline = [], time.monotonic() + 60
    for line in proc.stdout:
        seen.append(line)
        if "[env_sim]" in line and "waiting for" in line:
            break
        assert time.monotonic() < deadline, "".join(seen)
    time.sleep(2.0)  # the graph is stepping
    nodes = _children(proc.pid)
    assert len(nodes) == 4, "".join(seen)
    return proc, nodes, "".join(seen)


def _wait_gone(pids: list, timeout: float = 30.0) -> list:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.2)
    return [p for p in pids if _alive(p)]


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_an_interrupted_launch_stops_its_nodes_and_says_so(ros_domain, sig, code):
    """Finding 6: SIGHUP (terminal closed) left the nodes running; an interrupted run exited 0."""
    proc, nodes, head = _started_graph()
    proc.send_signal(sig)
    rc, out = finish(proc, 60)
    assert rc == code, head + out
    assert f"interrupted by {signal.Signals(sig).name}: 4 node(s) stopped" in out
    assert "exited cleanly" not in out
    assert _wait_gone(nodes) == []


def test_nodes_do_not_outlive_a_killed_launcher(ros_domain):
    """Finding 6: after SIGKILL of `nmrm launch` its nodes kept running with parent 1."""
    proc, nodes, _ = _started_graph()
    proc.kill()
    proc.wait()
    left = _wait_gone(nodes)
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert left == []


# -- the graph heals: a bad message or a node restart costs at most the episode in progress --------
EPISODES = 12
FAST = {"action_timeout": 0.5, "max_retries": 2}  # an abandoned episode costs ~1.5 s, not 20 s


def _graph_params(tmp_path) -> Path:
    import yaml

    from graph_helpers import REPO

    params = yaml.safe_load((REPO / "config" / "graph.yaml").read_text())
    params["/**/env_sim"]["ros__parameters"].update(FAST)
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump(params))
    return path


def _summary(out: str) -> str:
    lines = [line for line in out.splitlines() if "[env_sim]" in line and "done:" in line]
    assert lines, out
    return lines[-1]


def _abandoned(out: str) -> int:
    import re

    return int(re.search(r"(\d+) episode\(s\) abandoned", _summary(out)).group(1))


def test_bad_observations_cost_at_most_their_episode(ros_domain, tmp_path):
    """Finding 1: one malformed observation stopped the whole graph (2 of 20 episodes done)."""
    from graph_helpers import Capture
    from nmrm_msgs.msg import EnvObservation
    from nmrm_ros.ros.topics import OBSERVATION

    cap = Capture()
    try:
        pub = cap.publisher(EnvObservation, OBSERVATION)
        proc = launch(f"episodes:={EPISODES}", f"params:={_graph_params(tmp_path)}", "wait_for_subscribers:=3")
        assert cap.spin_until(lambda: len(cap.msgs["observation"]) >= 150, 60)
        faults = [dict(step=5, state=[float("nan"), 0.5]),      # NaN
                  dict(step=7, state=[0.5, 0.5, 0.5]),           # wrong size
                  dict(step=90, state=[0.5, 0.5]),               # from the future
                  dict(step=1, state=[0.9, 0.1])]                # from the past, another state
        for fault in faults:
            current = cap.msgs["observation"][-1]
            pub.publish(EnvObservation(task="key", episode=current.episode, **fault))
            n = len(cap.msgs["observation"])
            assert cap.spin_until(lambda n=n: len(cap.msgs["observation"]) >= n + 150, 60)
        cap.node.destroy_publisher(pub)  # else the consumers' upstream never leaves
        cap.spin_until(lambda: proc.poll() is not None, 120)
        code, out = finish(proc, 30)
    finally:
        cap.close()
    assert code == 0, out
    assert f"done: {EPISODES} episodes" in _summary(out)
    assert _abandoned(out) <= len(faults), _summary(out)
    labelled = int(out.split("labelled ")[-1].split(" ")[0])
    assert labelled >= EPISODES - len(faults), out


def test_a_killed_and_restarted_reward_model_costs_one_episode(ros_domain, tmp_path):
    """Finding 1: after kill -9 and a restart of reward_model the loop never resumed."""
    from graph_helpers import Capture, start

    episodes = 30
    cap = Capture()
    try:
        env = start("env_sim", task="key", episodes=episodes, wait_for_subscribers=3,
                    wait_for_nodes="[labeller_oracle, reward_model]", start_delay=1.0, **FAST)
        lab = start("labeller_oracle", task="key", exit_with_upstream=True)
        agent = start("agent", task="key", exit_with_upstream=True)
        rm = start("reward_model", mode="oracle", task="key")
        # kill -9 in the middle of episode 3, restart with the same parameters
        assert cap.spin_until(lambda: any(m.episode == 3 and m.step == 50 for m in cap.msgs["observation"]), 60)
        rm.kill()
        rm.wait()
        rm2 = start("reward_model", mode="oracle", task="key", exit_with_upstream=True)
        cap.spin_until(lambda: env.poll() is not None, 120)
        code, out = finish(env, 30)
        assert code == 0, out
        assert f"done: {episodes} episodes" in _summary(out)
        assert _abandoned(out) <= 1, _summary(out)
        for p in (lab, rm2, agent):
            c, o = finish(p, 30)
            assert c == 0, o
        labels = {m.episode for m in cap.msgs["label"]}
        assert len(labels) >= episodes - 1, sorted(labels)
    finally:
        cap.close()
