"""Benchmark: what an image task's episodes cost on the graph and in a bag.

    .venv/bin/python bench/image_bags.py [--episodes 20] [--seed 1]

Writes the screened episodes of data seed --seed of Key, as the state task and as the pixel task
(key_pixels: 32 x 32 x 3 images, the position privileged), with `write_dataset_bag` (what `nmrm
dataset generate` writes: the pixels as a PNG on /nmrm/observation_image beside each
EnvObservation, as the recorder records env_sim), and prints per task: steps,
the bag's size per 1000 steps (MCAP files, zstd-compressed chunks), the writing rate (steps/s,
dataset -> bag, one thread), and the serialized bytes a step of each topic (what a subscriber
receives on the graph: uncompressed).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import tempfile
import time
from pathlib import Path


def measure(ds, out: Path) -> str:
    from nmrm_ros.bags.episodes import write_dataset_bag
    from nmrm_ros.bags.reader import iter_raw

    t0 = time.perf_counter()
    bag = write_dataset_bag(ds, out)
    seconds = time.perf_counter() - t0
    steps = int((ds.lengths + 1).sum())
    size = sum(f.stat().st_size for f in Path(bag).rglob("*.mcap"))
    per_topic: dict = {}
    for raw in iter_raw(bag):
        per_topic[raw.topic] = per_topic.get(raw.topic, 0) + len(raw.data)
    topics = ", ".join(f"{topic} {n / steps:,.0f}" for topic, n in sorted(per_topic.items(), key=lambda kv: -kv[1]))
    return (f"{ds.task:11s} {steps} steps: {size / steps * 1000 / 1e6:.3f} MB per 1000 steps, written at "
            f"{steps / seconds:,.0f} steps/s; bytes a step: {topics}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.tasks.pixel_navigation import pixel_dataset

    ds = generate_screened("key", args.episodes, seed=args.seed)
    print(f"# {args.episodes} screened Key episodes of data seed {args.seed}")
    with tempfile.TemporaryDirectory() as tmp:
        print(measure(ds, Path(tmp) / "key"))
        print(measure(pixel_dataset(ds, "key_pixels"), Path(tmp) / "key_pixels"))


if __name__ == "__main__":
    main()
