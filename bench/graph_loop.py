"""Benchmark: the env_sim -> reward_model -> agent loop (separate processes, real topics) with a random
agent, the oracle labeller watching, and a real CSC checkpoint; prints loop steps/s (from env_sim)
and the reward node's compute per step (median, p99, from its log).

    .venv/bin/python bench/graph_loop.py [--episodes 50] [--task key] [--checkpoint PATH]

Without --checkpoint, a CSC model is trained first (screened Key data, 1000 trajectories, 20
epochs, seed 0). Run with scripts/ros_env.sh sourced (AMENT_PREFIX_PATH, ROS_DOMAIN_ID).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import re
import subprocess
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--task", default="key")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--mode", default="model", choices=["model", "oracle"])
    args = parser.parse_args()
    checkpoint = args.checkpoint
    if checkpoint is None and args.mode == "model":
        from nmrm_ros.datasets import generate_screened
        from nmrm_ros.mil import load_train_config
        from nmrm_ros.mil.pipeline import fit

        ds = generate_screened(args.task, 1000, seed=0)
        out = Path(tempfile.mkdtemp()) / f"{args.task}_csc"
        run = fit(ds, "csc_lstm", load_train_config(args.task, max_epochs=20), out=out,
                                 progress=False)
        checkpoint = str(run.checkpoint)
    cmd = ["nmrm", "launch", str(REPO / "launch_scripts" / "graph.launch.yaml"), f"task:={args.task}",
           f"episodes:={args.episodes}", f"mode:={args.mode}", f"checkpoint:={checkpoint or ''}"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=3600).stdout
    done = re.search(r"done: (\d+) episodes, (\d+) steps in ([\d.]+) s \((\d+) steps/s\)", out)
    compute = re.search(r"compute per step(?: \(the last \d+\))?: median ([\d.]+) µs, p99 ([\d.]+) µs", out)
    if not done or not compute:
        raise SystemExit(f"graph run failed:\n{out}")
    print(f"# graph loop: env_sim -> reward_model ({args.mode}) -> agent (random), labeller_oracle "
          f"watching, task {args.task}, separate processes, EventsExecutor")
    print(f"loop: {done.group(2)} steps ({done.group(1)} episodes) in {done.group(3)} s = "
          f"{done.group(4)} steps/s")
    print(f"reward node compute per step: median {compute.group(1)} µs, p99 {compute.group(2)} µs")


if __name__ == "__main__":
    main()
