"""Benchmark: per-step latency of the online reward model (what the reward-model node runs), for
each architecture at 2D-navigation and Lunar Lander sizes, and for a 10-member CSC ensemble.

    .venv/bin/python bench/online_step.py [--steps 20000]
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import time

import numpy as np
import torch

from nmrm_ros.mil import ARCHITECTURES, OnlineRewardModel, build_model, model_config
from nmrm_ros.mil.ensemble import init_ensemble


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"# online step latency, {args.steps} steps, episodes of 100 (reset every 100 steps)")
    print(f"{'task family':13s} {'architecture':15s} {'median µs':>10s} {'p99 µs':>8s}")
    for task, d in (("key", 2), ("lunar_lander", 8)):
        states = np.random.default_rng(0).normal(size=(args.steps, d)).astype(np.float32)
        for arch in (*ARCHITECTURES, "csc_lstm x10"):
            torch.manual_seed(0)
            if arch.endswith("x10"):
                online = OnlineRewardModel(init_ensemble(model_config("csc_lstm", task, d), range(10)))
            else:
                online = OnlineRewardModel(build_model(model_config(arch, task, d)))
            times = np.empty(args.steps)
            for i in range(args.steps):
                if i % 100 == 0:
                    online.reset()
                t0 = time.perf_counter()
                online.step(states[i])
                times[i] = time.perf_counter() - t0
            print(f"{task:13s} {arch:15s} {np.median(times) * 1e6:10.1f} {np.percentile(times, 99) * 1e6:8.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
