"""Where a model's reward error lies: the part that is a function of the step index alone.

    .venv/bin/python bench/reward_decomposition.py --checkpoint runs/rel/timer_head/timer_csc_lstm
    .venv/bin/python bench/reward_decomposition.py --checkpoint A B --plot bench/results/x.png

For each member of a `bench/reproduce_tables.py --save` ensemble (member m: repeat r = its
seed, tested on its own split r of the checkpoint's dataset, as the table does; a single model:
its test split), prints the test reward MSE, the part of it that is the mean error per step
index t (`reward_mse_time_profile`, nmrm_ros.mil.evaluation), the sum over t of that mean error
(return units: near zero when the profile is invisible in the returns, as a zero-sum function of
time is when every bag has the same length), the mean error at a few steps, and the mean error
and MSE on four groups of steps: where the oracle's reward is non-zero or zero, in the first or
second half of the bag (t <= 50 or t > 50 for bags of 100: Timer's switch). A model that defers
a reward (pays a step's reward later, remembered in its hidden state) shows errors of opposite
sign in the two halves, and its bags' summed errors in the first and second half cancel
("deferred": their correlation and regression slope near -1; the std of the first-half sums says
how much is moved). --plot draws each member's mean error per step.

Why it matters: when all bags are equally long, rewards r_t + f(t) with sum_t f(t) = 0 give every
bag the same return as r_t, so the return labels cannot tell them apart, and a model with a
hidden state that counts steps can learn any such f.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
from pathlib import Path

import numpy as np
import torch

from nmrm_ros.datasets.cache import cached_dataset


@torch.no_grad()
def step_errors(model, ds) -> tuple[np.ndarray, np.ndarray]:
    """(err, real): (n, T) predicted r'_t - oracle r_t of every bag (0 beyond its length), and
    (n, T) whether step t is a real step of bag i."""
    from nmrm_ros.mil.data import BagTensors

    bags = BagTensors(ds)
    x, lengths, _ = bags.batch(torch.arange(len(bags)))
    real = np.arange(x.shape[1])[None, :] < ds.lengths[:, None]
    err = (model(x, lengths).rewards.double().numpy() - ds.rewards[:, : x.shape[1]]) * real
    return err, real


def mean_error_by_step(err: np.ndarray, real: np.ndarray) -> np.ndarray:
    """(T,) mean over the bags of the error, per step index t."""
    return err.sum(0) / np.maximum(real.sum(0), 1)


def grouped_errors(err: np.ndarray, real: np.ndarray, true: np.ndarray) -> dict:
    """{group: (mean error, MSE)} over the steps of four groups: oracle reward `true` (n, T)
    non-zero / zero, step t <= T / 2 or later (T: the longest bag); and "deferred": (correlation,
    slope, std of the first) between each bag's summed error in its first half and in its second."""
    T = err.shape[1]
    true = true[:, :T]
    first = np.broadcast_to(np.arange(T)[None, :] <= T // 2, real.shape)
    # deferred credit: a bag's error in its first half paid back in its second (slope ~ -1)
    e1 = np.where(first, err, 0.0).sum(1)
    e2 = np.where(~first, err, 0.0).sum(1)
    slope = float(np.polyfit(e1, e2, 1)[0]) if e1.std() > 0 else 0.0
    groups = {"deferred": (float(np.corrcoef(e1, e2)[0, 1]) if e1.std() > 0 and e2.std() > 0 else 0.0,
                           slope, float(e1.std()))}
    for name, sel in (("reward, 1st half", (true != 0) & first), ("reward, 2nd half", (true != 0) & ~first),
                      ("no reward, 1st half", (true == 0) & first), ("no reward, 2nd half", (true == 0) & ~first)):
        sel = sel & real
        groups[name] = (float(err[sel].mean()), float((err[sel] ** 2).mean())) if sel.any() else (0.0, 0.0)
    return groups


def members(path: Path):
    """(label, model, test dataset) per member of the checkpoint at `path`."""
    from nmrm_ros.mil import load_checkpoint
    from nmrm_ros.mil.data import split_indices

    model, meta = load_checkpoint(path)
    source = meta.data.source
    n = int(meta.data.n)
    data_seed = int(meta.data.meta.get("seed", 0))
    ds = cached_dataset(meta.task, n, data_seed)
    if source.kind not in ("screened", ""):
        print(f"# note: {path}: data source {str(source)!r}; using the screened dataset n={n}, seed {data_seed}")
    split_seeds = meta.ensemble.split_seeds or [int(meta.split_seed or 0)] * model.members
    seeds = meta.ensemble.seeds or [meta.seed]
    for m in range(model.members):
        test = split_indices(len(ds), int(split_seeds[m]))[2]
        yield f"seed {seeds[m]} split {split_seeds[m]}", model.member(m), ds.subset(test)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, nargs="+", required=True)
    parser.add_argument("--plot", type=Path, default=None, help="PNG of the mean error per step")
    args = parser.parse_args()
    from nmrm_ros.mil import evaluate

    curves = []
    for path in args.checkpoint:
        print(f"# {path}")
        print(f"  {'member':22s} {'return MSE':>10s} {'reward MSE':>10s} {'time prof.':>10s} "
              f"{'share':>6s} {'sum_t err':>9s}  mean error at t = 10, 30, 50, 70, 90 | mean error/MSE: "
              "reward 1st half, 2nd half; no reward 1st half, 2nd half | deferred credit")
        for label, model, test in members(path):
            m = evaluate(model, test)
            err, real = step_errors(model, test)
            profile = mean_error_by_step(err, real)
            share = m["reward_mse_time_profile"] / max(m["reward_mse"], 1e-12)
            at = " ".join(f"{profile[t]:+.3f}" for t in (10, 30, 50, 70, 90) if t < len(profile))
            grouped = grouped_errors(err, real, test.rewards)
            corr, slope, spread = grouped.pop("deferred")
            groups = "  ".join(f"{e:+.3f}/{q:.3f}" for e, q in grouped.values())
            groups += f" | deferred: corr {corr:+.2f}, slope {slope:+.2f}, 1st-half error sum std {spread:.2f}"
            print(f"  {label:22s} {m['return_mse']:10.4f} {m['reward_mse']:10.5f} "
                  f"{m['reward_mse_time_profile']:10.5f} {share:6.0%} {profile.sum():+9.3f}  {at} | {groups}")
            curves.append((f"{path.name} {label}", profile, m["reward_mse"]))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(9, 4.5))
        for label, profile, mse in curves:
            ax.plot(profile, lw=1.5 if mse > 0.03 else 0.7, label=f"{label} (reward MSE {mse:.3f})")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("step t")
        ax.set_ylabel("mean over test bags of r'_t - r_t")
        ax.legend(fontsize=6, ncol=2)
        fig.tight_layout()
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.plot, dpi=110)
        print(f"# plot: {args.plot}")


if __name__ == "__main__":
    main()
