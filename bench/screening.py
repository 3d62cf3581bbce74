"""Benchmark: screened dataset generation (paper App. D.2), draws and wall time per task.

    .venv/bin/python bench/screening.py [--n 5000] [--seed 0] [--lander-pool 2000]

Prints one row per task: trajectories kept, trajectories drawn (examined), seconds, draws/s.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import platform
import time

import numpy as np

from nmrm_ros.datasets import generate_screened


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=5000, help="trajectories per navigation dataset")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--lander-pool", type=int, default=2000,
                        help="Lunar Lander pool size (scripted controller); limit 0.2 of the pool")
    parser.add_argument("--tasks", nargs="*", default=["timer", "moving", "key", "charger", "lunar_lander"])
    args = parser.parse_args()
    print(f"# screening benchmark: seed {args.seed}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores")
    print(f"{'task':14s} {'kept':>6s} {'drawn':>10s} {'seconds':>8s} {'draws/s':>10s} {'classes':>7s}")
    for task in args.tasks:
        start = time.perf_counter()
        if task == "lunar_lander":
            ds = generate_screened(task, args.lander_pool, seed=args.seed, pool_size=args.lander_pool)
        else:
            ds = generate_screened(task, args.n, seed=args.seed)
        seconds = time.perf_counter() - start
        draws = ds.meta["draws"]
        print(f"{task:14s} {len(ds):6d} {draws:10d} {seconds:8.2f} {draws / seconds:10.0f} "
              f"{len(np.unique(ds.classes)):7d}", flush=True)


if __name__ == "__main__":
    main()
