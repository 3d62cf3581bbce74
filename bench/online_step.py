"""Benchmark: per-step latency of the online reward model (what the reward-model node runs), for
each architecture at 2D-navigation and Lunar Lander sizes, for a 10-member CSC ensemble, and for
3-member models of image states (32 x 32 x 3 and 64 x 64 x 3, the image encoder included).

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


def cases():
    """(task family, architecture label, state size, a function making the model)."""
    from dataclasses import replace

    for task, d in (("key", 2), ("lunar_lander", 8)):
        for arch in ARCHITECTURES:
            yield task, arch, d, lambda arch=arch, task=task, d=d: build_model(model_config(arch, task, d))
        yield task, "csc_lstm x10", d, lambda task=task, d=d: init_ensemble(model_config("csc_lstm", task, d), range(10))
    # image states (issue 53): the pixel tasks' 32 x 32 x 3, and 64 x 64 x 3 with the same encoder
    for size in (32, 64):
        d = size * size * 3
        for arch in ARCHITECTURES:
            cfg = replace(model_config(arch, "key_pixels", 3072), input_size=d, image_shape=(size, size, 3))
            yield f"pixels {size}x{size}", f"{arch} x3", d, lambda cfg=cfg: init_ensemble(cfg, range(3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"# online step latency, {args.steps} steps, episodes of 100 (reset every 100 steps), one thread")
    print(f"{'task family':13s} {'architecture':18s} {'median µs':>10s} {'p99 µs':>8s}")
    for task, arch, d, make in cases():
        states = np.random.default_rng(0).integers(0, 256, size=(args.steps, d)).astype(np.float32) \
            if task.startswith("pixels") else np.random.default_rng(0).normal(size=(args.steps, d)).astype(np.float32)
        torch.manual_seed(0)
        online = OnlineRewardModel(make())
        times = np.empty(args.steps)
        for i in range(args.steps):
            if i % 100 == 0:
                online.reset()
            t0 = time.perf_counter()
            online.step(states[i])
            times[i] = time.perf_counter() - t0
        print(f"{task:13s} {arch:18s} {np.median(times) * 1e6:10.1f} {np.percentile(times, 99) * 1e6:8.1f}",
              flush=True)


if __name__ == "__main__":
    main()
