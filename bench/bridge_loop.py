"""Loop rate and per-step latency through the robot bridges, against the plain graph.

    source scripts/ros_env.sh && .venv/bin/python bench/bridge_loop.py [--episodes 20] [--rates 10 40 200]

Each graph runs under `nmrm launch` with the reward model in oracle mode, a random agent and the
recorder, and is measured from its bag: the per-step latency is an action's header stamp minus its
observation's (the producer stamps the observation as it publishes it, the agent its action as it
publishes it; one machine, one clock), i.e. producer -> reward_model -> agent; the loop rate is
steps over the time from an episode's first to its last observation, over all episodes.
  plain:  graph.launch.yaml (env_sim -> reward_model -> agent, lockstep: the next step once the
          action is in), task key, and a recorder;
  bridge: robot_bridge.launch.yaml with the fake robot (Odometry -> observation_bridge ->
          reward_model -> agent -> action_bridge -> Twist), its spec's rate set to each of --rates
          (the bridge samples at that rate: a step does not wait for the action), 20 steps an episode.
Prints a table and writes bench/results/bridge_loop.txt.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import signal
import subprocess
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULT = ROOT / "bench" / "results" / "bridge_loop.txt"


def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def measure(bag: Path) -> dict:
    """Latency (ms) of every action after its observation, and the loop rate (steps/s)."""
    from nmrm_ros.bags import iter_decoded

    obs, act = {}, {}
    by_episode = defaultdict(list)
    for topic, _, _, msg in iter_decoded(bag):
        if topic.endswith("/nmrm/observation"):
            obs[(msg.episode, msg.step)] = _stamp(msg)
            by_episode[msg.episode].append(_stamp(msg))
        elif topic.endswith("/nmrm/action"):
            act[(msg.episode, msg.step)] = _stamp(msg)
    lat = np.array([(act[k] - obs[k]) / 1e6 for k in act if k in obs])
    steps = sum(len(s) - 1 for s in by_episode.values())
    span = sum((max(s) - min(s)) / 1e9 for s in by_episode.values())
    return {"latency_ms": lat, "steps": steps, "rate": steps / span if span else float("nan"),
            "episodes": len(by_episode)}


def run(cmd: list, timeout: float) -> str:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate()
        raise SystemExit(f"timed out: {' '.join(cmd)}\n{out[-2000:]}")
    if proc.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{out[-3000:]}")
    return out


def plain(work: Path, episodes: int) -> dict:
    bag = work / "plain"
    rec = subprocess.Popen([str(Path(os.environ["NMRM_VENV"]) / "bin" / "recorder"), "--ros-args", "-p",
                            f"output:={bag}", "-p", "exit_with_upstream:=true"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    run(["nmrm", "launch", str(ROOT / "launch_scripts" / "graph.launch.yaml"), "task:=key",
         f"episodes:={episodes}", "wait_for_subscribers:=3", "start_delay:=1.0"], 600)
    rec.wait(60)
    return measure(bag)


def bridge(work: Path, episodes: int, rate: float) -> dict:
    spec = (ROOT / "config" / "robots" / "fake_delivery.yaml").read_text()
    spec = spec.replace("rate: 10.0                  # Hz", f"rate: {rate}                  # Hz")
    spec = spec.replace("max_steps: 200", "max_steps: 20")
    path = work / f"spec_{rate:g}.yaml"
    path.write_text(spec)
    bag = work / f"bridge_{rate:g}"
    run(["nmrm", "launch", str(ROOT / "launch_scripts" / "robot_bridge.launch.yaml"), f"spec:={path}",
         f"episodes:={episodes}", f"out:={bag}", "task:=nmrm_ros.robots.delivery:DeliveryEnv,max_steps=20,xy=0/1"],
        600)
    return measure(bag)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 40.0, 200.0])
    parser.add_argument("--note", default="", help="what else ran on the machine (written with the result)")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bridge_loop_"))
    rows = [("plain graph (env_sim, lockstep)", plain(work, args.episodes))]
    rows += [(f"bridges, spec rate {r:g} Hz", bridge(work, args.episodes, r)) for r in args.rates]
    lines = ["# per-step latency: action stamp - observation stamp (producer -> reward_model -> agent), ms",
             "# loop rate: steps / (last - first observation stamp) per episode, summed; task key (plain) /",
             "# the fake robot's delivery task (bridges); reward_model in oracle mode, random agent, recorder on",
             f"{'graph':36s} {'episodes':>8s} {'steps':>6s} {'steps/s':>8s} {'median':>7s} {'p90':>7s} {'p99':>7s}"]
    for name, m in rows:
        lat = m["latency_ms"]
        lines.append(f"{name:36s} {m['episodes']:8d} {m['steps']:6d} {m['rate']:8.1f} {np.median(lat):7.2f} "
                     f"{np.percentile(lat, 90):7.2f} {np.percentile(lat, 99):7.2f}")
    lines.append(f"# command: bench/bridge_loop.py --episodes {args.episodes} --rates "
                 f"{' '.join(f'{r:g}' for r in args.rates)} ({time.strftime('%Y-%m-%d')}, 2-core machine"
                 f"{'; ' + args.note if args.note else ''})")
    text = "\n".join(lines)
    print(text)
    RESULT.write_text(text + "\n")


if __name__ == "__main__":
    main()
