"""Benchmark: one learner fed by a fleet of N robots on this machine (`nmrm fleet`), N = 1, 2, 4, 8.

For each N: N namespaced graphs (env_sim, reward_model in oracle mode, labeller_oracle) and one
learning agent (double DQN, config/rl.yaml: one gradient step per fleet step) with the fleet's
recorder, `--episodes` episodes per robot. Prints per N:
- learner steps/s: transitions that reached the learner per second of wall time, from its
  curve.csv, between the end of the fleet's first episodes and the end of its last (start-up of
  the 3N + 2 processes excluded);
- fleet steps/s: vectorised-env steps per second (each carries N transitions, one gradient step);
- messages published (counted from each env_sim's own summary: observations and reward steps
  101 per episode, actions and oracle steps 100, one label; plus one observation and reward step
  per re-publication after an action timeout, which there should not be) vs recorded in the bag.

    .venv/bin/python bench/fleet_scaling.py [--robots 1 2 4 8] [--episodes 5] [--task key]

Run with scripts/ros_env.sh sourced.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import csv
import re
import subprocess
import tempfile
import time
from pathlib import Path


def run_fleet(robots: int, episodes: int, task: str, out: Path) -> dict:
    t0 = time.monotonic()
    proc = subprocess.run(["nmrm", "fleet", "--robots", str(robots), "--episodes", str(episodes),
                           "--task", task, "--out", str(out), "--save-every", "0"],
                          capture_output=True, text=True, timeout=3600)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"fleet of {robots} failed:\n{proc.stdout[-5000:]}\n{proc.stderr[-2000:]}")
    from nmrm_ros.bags import bag_summary

    rows = list(csv.DictReader((out / "policy" / "curve.csv").open()))
    walls = sorted(float(r["wall_time"]) for r in rows)
    steps = sum(int(r["steps"]) for r in rows)
    first = [float(r["wall_time"]) for r in rows][:robots]
    measured_steps = steps - sum(int(r["steps"]) for r in rows[:robots])
    span = walls[-1] - max(first)
    done = re.findall(r"done: (\d+) episodes, (\d+) steps", proc.stdout)
    n_ep = sum(int(e) for e, _ in done)
    n_steps = sum(int(s) for _, s in done)
    published = {"observation": n_steps + n_ep, "reward_step": n_steps + n_ep, "action": n_steps,
                 "oracle_step": n_steps, "trajectory_return": n_ep}
    republished = proc.stdout.count("re-publishing the")  # each: one more observation and reward step
    published["observation"] += republished
    published["reward_step"] += republished
    recorded = {k: 0 for k in published}
    for topic, (_, count) in bag_summary(out / "bag").items():
        recorded[topic.rsplit("/", 1)[1]] += count
    return {"robots": robots, "episodes": len(rows), "learner_steps_per_s": measured_steps / span,
            "fleet_steps_per_s": measured_steps / robots / span, "wall": wall,
            "published": sum(published.values()), "recorded": sum(recorded.values()),
            "per_topic": {k: (published[k], recorded[k]) for k in published},
            "republished": republished}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--episodes", type=int, default=5, help="episodes per robot")
    parser.add_argument("--task", default="key")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="fleet_bench_"))
    print(f"# fleet scaling: task {args.task}, {args.episodes} episodes per robot, oracle reward, "
          f"double DQN learning from every robot; one machine ({subprocess.check_output(['nproc']).decode().strip()} cores)")
    print("| robots | processes | learner transitions/s | fleet steps/s | messages published | recorded | lost | re-published | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.robots:
        r = run_fleet(n, args.episodes, args.task, tmp / f"n{n}")
        print(f"| {n} | {3 * n + 2} | {r['learner_steps_per_s']:.0f} | {r['fleet_steps_per_s']:.0f} | "
              f"{r['published']} | {r['recorded']} | {r['published'] - r['recorded']} | {r['republished']} | "
              f"{r['wall']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
