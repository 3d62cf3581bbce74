"""What serving the mean of M independently trained models would score, from one saved run.

    .venv/bin/python bench/mean_of_members.py --checkpoint runs/rel/timer_l1_0.05/timer_csc_lstm --k 3 5

Takes a `bench/reproduce_tables.py --save` ensemble (its members: 10 repeats, each its own weight
seed and split of the data seed 0 dataset) and scores, on a dataset none of them saw (5000
screened bags of --data-seed, default 1), every member alone and the mean prediction of every
combination of k members: test return MSE and reward MSE, median and worst over the combinations,
and how many are over the paper's bar (mean + 2 SEM). An estimate of `nmrm train --ensemble k`
(whose members share one split) from members that did not; the real protocol is
`reproduce_tables.py --members k`.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import itertools
from pathlib import Path

import numpy as np
import torch

from nmrm_ros.paper import PAPER_RETURN, PAPER_REWARD
from nmrm_ros.datasets.cache import cached_dataset


@torch.no_grad()
def member_predictions(ens, ds, batch: int = 500) -> np.ndarray:
    """(K, n, T) every member's per-step rewards on the bags of `ds`."""
    from nmrm_ros.mil.data import BagTensors

    bags = BagTensors(ds)
    out = []
    for start in range(0, len(bags), batch):
        x, lengths, _ = bags.batch(torch.arange(start, min(start + batch, len(bags))))
        out.append(ens(x, lengths).rewards.double())
    return torch.cat(out, dim=1).numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--data-seed", type=int, default=1)
    parser.add_argument("--n", type=int, default=5000)
    parser.add_argument("--k", type=int, nargs="+", default=[3, 5])
    args = parser.parse_args()
    from nmrm_ros.mil import load_checkpoint

    ens, meta = load_checkpoint(args.checkpoint)
    task, arch = meta.task, ens.config.architecture
    ds = cached_dataset(task, args.n, args.data_seed)
    real = np.arange(ds.states.shape[1])[None, :] < ds.lengths[:, None]
    preds = member_predictions(ens, ds) * real  # (K, n, T)
    truth = ds.rewards * real
    steps = real.sum()

    def scores(p: np.ndarray) -> tuple[float, float]:
        return float(((p.sum(-1) - ds.returns) ** 2).mean()), float(((p - truth) ** 2).sum() / steps)

    bar_ret = PAPER_RETURN[arch][task][0] + 2 * PAPER_RETURN[arch][task][1]
    bar_rew = PAPER_REWARD[arch][task][0] + 2 * PAPER_REWARD[arch][task][1]
    seeds = meta.ensemble.seeds
    print(f"# {args.checkpoint}: {ens.members} members of {arch} on {task}; scored on {len(ds)} screened "
          f"bags of data seed {args.data_seed}; bars (paper mean + 2 SEM): return {bar_ret:.3f}, reward {bar_rew:.4f}")
    single = [scores(preds[m]) for m in range(ens.members)]
    for m, (ret, rew) in enumerate(single):
        print(f"  member {m} (seed {seeds[m]}): return MSE {ret:.4f}, reward MSE {rew:.5f}"
              f"{'  over the reward bar' if rew > bar_rew else ''}{'  over the return bar' if ret > bar_ret else ''}")
    for k in [1, *args.k]:
        combos = list(itertools.combinations(range(ens.members), k))
        s = np.array([scores(preds[list(c)].mean(0)) for c in combos])
        print(f"  mean of {k}: {len(combos)} combinations; return MSE median {np.median(s[:, 0]):.4f}, "
              f"worst {s[:, 0].max():.4f}, over the bar {int((s[:, 0] > bar_ret).sum())}; reward MSE median "
              f"{np.median(s[:, 1]):.5f}, worst {s[:, 1].max():.5f}, over the bar {int((s[:, 1] > bar_rew).sum())}")


if __name__ == "__main__":
    main()
