"""Benchmark: the graph on one host vs split over two (network namespaces joined by a veth link,
so every message crosses a real IP hop, as in tests/test_multi_host.py; needs root).

The same two launch files each time: launch_scripts/robot.launch.yaml (env_sim + a random agent)
and workstation.launch.yaml (reward_model in oracle mode, labeller_oracle, recorder), `--episodes`
Key episodes. Three set-ups:
- one host, Fast DDS defaults (shared memory between the processes);
- one host, UDP only (FASTDDS_BUILTIN_TRANSPORTS=UDPv4: the transport of two machines, no hop);
- two hosts (namespaces), UDP over the veth link, multicast discovery.
Prints the loop rate (env_sim's own summary: steps / time from first to last step) and the
per-step latency of the loop: AgentAction.header.stamp - EnvObservation.header.stamp of the same
(episode, step) as recorded (observation -> reward_model on the workstation -> RewardStep back
-> agent's action), median and p99. All processes share this machine's clock.

    sudo .venv/bin/python bench/split_graph.py [--episodes 30]

Run with scripts/ros_env.sh sourced.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import re
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
from nmrm_ros.testing.netns import HostsUnavailable, in_host, make_hosts, remove_hosts  # noqa: E402


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def step_latencies(bag: Path) -> np.ndarray:
    """Seconds from each observation's stamp to its action's stamp (non-final steps)."""
    from nmrm_ros.bags import iter_decoded

    sent, answered = {}, {}
    for topic, _, _, msg in iter_decoded(bag):
        if topic.endswith("/observation") and not (msg.terminated or msg.truncated):
            sent.setdefault((msg.episode, msg.step), _stamp(msg))  # the first publication
        elif topic.endswith("/action"):
            answered.setdefault((msg.episode, msg.step), _stamp(msg))
    return np.array([answered[k] - sent[k] for k in sent if k in answered])


def run_split(episodes: int, env: dict, robot_ns: str | None, workstation_ns: str | None, bag: Path) -> dict:
    def start(ns, *cmd):
        return in_host(ns, env, *cmd) if ns else in_host_local(env, *cmd)

    workstation = start(workstation_ns, "nmrm", "launch", str(REPO / "launch_scripts" / "workstation.launch.yaml"),
                        "task:=key", f"out:={bag}")
    robot = start(robot_ns, "nmrm", "launch", str(REPO / "launch_scripts" / "robot.launch.yaml"),
                  "task:=key", f"episodes:={episodes}")
    out_r, _ = robot.communicate(timeout=1800)
    out_w, _ = workstation.communicate(timeout=120)
    done = re.search(r"done: (\d+) episodes, (\d+) steps in ([\d.]+) s \((\d+) steps/s\)", out_r)
    if robot.returncode or workstation.returncode or not done:
        raise SystemExit(f"split graph failed:\n{out_r[-4000:]}\n{out_w[-4000:]}")
    lat = step_latencies(bag) * 1e3
    return {"steps_per_s": int(done.group(4)), "steps": int(done.group(2)), "median_ms": np.median(lat),
            "p99_ms": np.percentile(lat, 99), "n": len(lat)}


def in_host_local(env: dict, *cmd: str):
    import subprocess

    return subprocess.Popen(list(cmd), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=30)
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="split_bench_"))
    base = os.environ.copy()
    udp = dict(base, FASTDDS_BUILTIN_TRANSPORTS="UDPv4")
    print(f"# the loop env_sim -> reward_model (oracle) -> random agent, labeller + recorder on the "
          f"workstation side; Key, {args.episodes} episodes per set-up")
    print("| set-up | loop steps/s | per-step latency median | p99 | steps measured |")
    print("|---|---|---|---|---|")
    rows = [("one host, Fast DDS defaults (shared memory)", base, None, None),
            ("one host, UDP only", udp, None, None)]
    for label, env, r_ns, w_ns in rows:
        res = run_split(args.episodes, env, r_ns, w_ns, tmp / label.split(",")[1].strip().split()[0])
        print(f"| {label} | {res['steps_per_s']} | {res['median_ms']:.2f} ms | {res['p99_ms']:.2f} ms | {res['n']} |",
              flush=True)
    try:
        hosts, namespaces = make_hosts(routed=False)
    except HostsUnavailable as exc:
        print(f"| two hosts | skipped: {exc} | | | |")
        return
    try:
        env = dict(udp, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET")
        res = run_split(args.episodes, env, hosts.robot, hosts.workstation, tmp / "two_hosts")
        print(f"| two hosts (network namespaces, veth), UDP, multicast discovery | {res['steps_per_s']} | "
              f"{res['median_ms']:.2f} ms | {res['p99_ms']:.2f} ms | {res['n']} |", flush=True)
    finally:
        remove_hosts(namespaces)


if __name__ == "__main__":
    main()
