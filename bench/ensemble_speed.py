"""Benchmark: what an ensemble of K costs per epoch against one model, trained in one pass.

    .venv/bin/python bench/ensemble_speed.py [--task timer] [--members 10] [--epochs 3]

Both sides run the same trainer (nmrm_ros.mil.train_ensemble) on the same data (screened, data
seed 0; per-member splits for the ensemble, split 0 for the single model), config
config/mil_training.yaml, and are timed the same way: seconds per epoch (training steps and the
validation pass), median of --epochs epochs after one untimed warm-up epoch, for 1 and 2 torch
threads. The ratio uses each side's faster thread count. Nothing else should run meanwhile.

It also prints a floor: the same epoch's fully connected layers alone (batched matrix products of
every FC layer, forward and backward, at the ensemble's shapes; no activation, dropout, LSTM,
loss or optimiser), 20 steps timed after 3 warm-up steps and scaled to an epoch's steps. K
members can cost no less than that.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import time

import numpy as np
import torch

from nmrm_ros.datasets.cache import cached_dataset

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


def gemm_floor(ds, arch: str, members: int, threads: int, **overrides) -> float:
    """Seconds per epoch of the FC layers' batched products alone (forward + backward)."""
    cfg = load_train_config(ds.task, threads=threads, **overrides)
    config = model_config(arch, ds.task, ds.state_size, hidden_size=cfg.hidden_size)
    k = config.hidden_size if arch != "instance_nn" else 0
    head_in = {"instance_nn": config.fe_sizes[-1], "csc_lstm": config.fe_sizes[-1] + k}.get(arch, k)
    layers = (list(zip([config.input_size, *config.fe_sizes[:-1]], config.fe_sizes))
              + list(zip([head_in, *config.head_sizes], [*config.head_sizes, 1])))
    torch.set_num_threads(threads)
    rows = cfg.batch_size * int(ds.lengths.max())
    weights = [torch.randn(members, b, a, requires_grad=True) for a, b in layers]
    inputs = [torch.randn(members, rows, a) for a, _ in layers]
    for z in inputs[1:]:
        z.requires_grad_(True)  # hidden layers also pass a gradient back to their input

    def step() -> None:
        total = sum(torch.bmm(z, w.transpose(1, 2)).sum() for z, w in zip(inputs, weights))
        total.backward()

    for _ in range(3):
        step()
    start = time.perf_counter()
    for _ in range(20):
        step()
    steps_per_epoch = -(-int(round(0.8 * len(ds))) // cfg.batch_size)
    return (time.perf_counter() - start) / 20 * steps_per_epoch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="timer")
    parser.add_argument("--arch", default="csc_lstm")
    parser.add_argument("--members", type=int, default=10)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training-config overrides")
    args = parser.parse_args()
    from nmrm_ros.mil.training import parse_settings

    overrides = parse_settings(args.set)
    ds = cached_dataset(args.task, 5000, 0)
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
    floor = min(gemm_floor(ds, args.arch, args.members, t, **overrides) for t in (1, 2))
    print(f"floor: the FC layers' products alone for K = {args.members} take {floor:.2f} s/epoch "
          f"(best thread count) = {floor / best[1]:.2f}x one whole model's epoch")


if __name__ == "__main__":
    main()
