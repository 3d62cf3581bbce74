"""Benchmark: what an ensemble of K costs per epoch against one model, trained in one pass.

    .venv/bin/python bench/ensemble_speed.py [--task timer] [--members 10] [--epochs 3]

Both sides run the same trainer (nmrm_ros.mil.train_ensemble) on the same data (screened, data
seed 0; per-member splits for the ensemble, split 0 for the single model), config
config/mil_training.yaml, and are timed the same way: seconds per epoch (training steps and the
validation pass), median of --epochs epochs after one untimed warm-up epoch, for 1 and 2 torch
threads. The ratio uses each side's faster thread count. Nothing else should run meanwhile.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reproduce_tables import load_dataset  # noqa: E402

from nmrm_ros.mil import load_train_config, model_config  # noqa: E402
from nmrm_ros.mil.ensemble import init_ensemble  # noqa: E402
from nmrm_ros.mil.pipeline import member_splits  # noqa: E402
from nmrm_ros.mil.training import train_ensemble  # noqa: E402


def seconds_per_epoch(ds, arch: str, members: int, epochs: int, threads: int, **overrides) -> float:
    cfg = load_train_config(ds.task, max_epochs=epochs + 1, patience=epochs + 1, threads=threads, **overrides)
    splits, _ = member_splits(len(ds), members, 0, "per_member")
    ens = init_ensemble(model_config(arch, ds.task, ds.state_size, dropout=cfg.dropout), range(members))
    times: list = []
    train_ensemble(ens, ds, [(tr, va) for tr, va, _ in splits], cfg, progress=False,
                   on_epoch=lambda e: times.append(e["seconds"]) and False)
    return float(np.median(np.diff(times)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="timer")
    parser.add_argument("--arch", default="csc_lstm")
    parser.add_argument("--members", type=int, default=10)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training-config overrides")
    args = parser.parse_args()
    from reproduce_tables import parse_overrides

    overrides = parse_overrides(args.set)
    ds = load_dataset(args.task, 5000, 0)
    print(f"# ensemble cost: {args.arch} on {args.task} (5000 bags, 4000 train), overrides {overrides}; "
          f"seconds per epoch, median of {args.epochs} after a warm-up epoch", flush=True)
    best = {}
    for members in (1, args.members):
        for threads in (1, 2):
            s = seconds_per_epoch(ds, args.arch, members, args.epochs, threads, **overrides)
            best[members] = min(best.get(members, np.inf), s)
            print(f"K = {members:2d}, {threads} thread(s): {s:6.2f} s/epoch", flush=True)
    ratio = best[args.members] / best[1]
    print(f"K = {args.members} costs {ratio:.2f}x one model per epoch (best thread count each); "
          f"{ratio / args.members:.2f}x per member")


if __name__ == "__main__":
    main()
