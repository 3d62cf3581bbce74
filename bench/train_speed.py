"""Benchmark: MIL training speed, one bag per step (as the paper trained) vs our padded mini-batches,
on the same model (CSC Instance Space LSTM, 2D-navigation sizes) and data (screened Key, seed 0).

    .venv/bin/python bench/train_speed.py [--epochs-batched 3] [--bags-single 1000] [--full]

Prints seconds per epoch of each (the one-bag-per-step epoch is timed on --bags-single bags and
scaled to the whole training split), their ratio, and with --full the wall time of a complete
training run (early stopping, config/mil_training.yaml) on the 5000-bag dataset.
"""

from __future__ import annotations

import argparse
import time

import torch

from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import build_model, load_train_config, model_config
from nmrm_ros.mil.data import BagTensors, split_indices
from nmrm_ros.mil.pipeline import train_and_evaluate
from nmrm_ros.mil.training import fit_normalisation


def epoch_seconds(model, bags: BagTensors, batch_size: int, n_bags: int, lr: float) -> float:
    """Time one pass of Adam steps over the first n_bags bags in batches of batch_size."""
    optimiser = torch.optim.Adam(model.parameters(), lr=lr)
    model.train()
    start = time.perf_counter()
    for i in range(0, n_bags, batch_size):
        x, lengths, returns = bags.batch(torch.arange(i, min(i + batch_size, n_bags)))
        loss = torch.mean((model(x, lengths).returns - returns) ** 2)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="key")
    parser.add_argument("--epochs-batched", type=int, default=3)
    parser.add_argument("--bags-single", type=int, default=1000)
    parser.add_argument("--full", action="store_true", help="also time a complete training run")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ds = generate_screened(args.task, 5000, seed=0)
    train_idx, val_idx, _ = split_indices(len(ds), 0)
    train = ds.subset(train_idx)
    cfg = load_train_config(args.task)
    bags = BagTensors(train)
    n = len(bags)

    torch.manual_seed(0)
    model = build_model(model_config("csc_lstm", args.task, 2, dropout=cfg.dropout))
    fit_normalisation(model, train, cfg)
    single = epoch_seconds(model, bags, 1, args.bags_single, cfg.lr) * n / args.bags_single
    batched = min(epoch_seconds(model, bags, cfg.batch_size, n, cfg.lr) for _ in range(args.epochs_batched))
    print(f"# train speed: csc_lstm, {args.task}, {n} training bags x 100 steps, 1 torch thread")
    print(f"one bag per step (paper):   {single:8.2f} s/epoch (timed on {args.bags_single} bags)")
    print(f"batched (batch {cfg.batch_size}):        {batched:8.2f} s/epoch (best of {args.epochs_batched})")
    print(f"speed-up:                   {single / batched:8.1f}x")
    if args.full:
        run = train_and_evaluate(ds, "csc_lstm", cfg, split_seed=0, progress=False)
        print(f"full training run (5000 bags, lr {cfg.lr}, patience {cfg.patience}, <= {cfg.max_epochs} "
              f"epochs): {run.train.seconds:.0f} s, {run.train.epochs_run} epochs (best {run.train.best_epoch}), "
              f"test return MSE {run.test_metrics['return_mse']:.4f}, reward MSE {run.test_metrics['reward_mse']:.5f}")


if __name__ == "__main__":
    main()
