"""Datasets kept on disk by task, size and data seed, made again when today's generator would
make other ones: what the benchmarks (and a user repeating them) train on.

    ds = cached_dataset("key", 5000, seed=0, root="runs/data")   # runs/data/key_n5000_s0.npz
"""

from __future__ import annotations

from pathlib import Path

from .screening import generate_screened
from .toy import TOY_DATASETS, make_toy_dataset
from .trajectories import TrajectoryDataset


def cached_dataset(task: str, n: int, seed: int, root: str | Path = "runs/data") -> TrajectoryDataset:
    """`n` episodes of `task` with data seed `seed` (screened; a toy dataset's own generator),
    from `root`/<task>_n<n>_s<seed>.npz if it is there and today's generator made it, else made
    (and saved there); a pixel task's: its state task's, rendered."""
    if task not in TOY_DATASETS:
        from ..tasks import task_info

        info = task_info(task)
        if info.pixels_of:  # rendered from the state task's (not kept: rendering takes seconds)
            from ..tasks.pixel_navigation import pixel_dataset

            return pixel_dataset(cached_dataset(info.pixels_of, n, seed, root), task)
    path = Path(root) / f"{task}_n{n}_s{seed}.npz"
    if path.is_file():
        cached = TrajectoryDataset.load(path)
        stale = stale_data(cached.meta, task)
        if not stale:
            return cached
        print(f"# {path.name}: made by another generator ({', '.join(stale)}): generating again", flush=True)
    ds = make_toy_dataset(task, n, seed=seed) if task in TOY_DATASETS else generate_screened(task, n, seed=seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save(path)
    return ds


def stale_data(recorded_meta: dict | None, task: str) -> list[str]:
    """How a cached dataset (its meta) or a model's recorded training data (a checkpoint's
    `meta.data.meta`) differs from what today's generator makes for `task`: Lunar Lander's scripted
    plans are versioned (`nmrm_ros.tasks.lunar_lander.SCRIPTED_PLANS`; data without a version are
    version 1); a frozen encoder's states are of the weights file whose SHA-256 the data recorded
    (`encoder_sha256`; `gym_task.encoder_weights_changed`). Empty when current, or when the data were
    not generated (a bag, a file of the user's)."""
    if not recorded_meta:
        return []
    from ..tasks.gym_task import encoder_weights_changed

    changed = encoder_weights_changed(task, recorded_meta.get("encoder_sha256"))
    stale = [changed] if changed else []
    if recorded_meta.get("policy") != "scripted":  # only Lunar Lander's pools are scripted
        return stale
    from ..tasks.lunar_lander import SCRIPTED_PLANS

    then = recorded_meta.get("plans", 1)
    return stale + ([] if then == SCRIPTED_PLANS else [f"scripted plans {then} -> {SCRIPTED_PLANS}"])
