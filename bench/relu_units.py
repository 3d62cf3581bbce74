"""Benchmark: which runs end with a dead ReLU unit. Trains the 10 repeats of a (task,
architecture) as `reproduce_tables.py` does (repeat r: weight seed r on split r, one ensemble) and
prints, per repeat, the test MSEs and the fraction of the dataset's instances on which each unit of
the first feature-extractor layer is > 0, at initialisation and after training (0.000: a dead unit,
which gets no gradient).

    .venv/bin/python bench/relu_units.py --task dial --arch csc_lstm
    .venv/bin/python bench/relu_units.py --task dial --set relu_bias=0       # torch's init
    .venv/bin/python bench/relu_units.py --task dial --set relu_bias=1.0 lstm_forget_bias=1.0
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import time

import numpy as np
import torch

from nmrm_ros.datasets.cache import cached_dataset
from nmrm_ros.mil.training import parse_settings

from nmrm_ros.mil import load_train_config, model_config
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.mil.training import initialise


def active_fractions(model, states: torch.Tensor) -> np.ndarray:
    """(units,) fraction of `states` (N, d, raw) on which each first-layer unit is > 0."""
    with torch.no_grad():
        z = model.feature_extractor[0]((states - model.input_shift) / model.input_scale)
    return (z > 0).float().mean(0).numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="dial")
    parser.add_argument("--arch", default="csc_lstm")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training-config overrides")
    args = parser.parse_args()
    ds = cached_dataset(args.task, 5000, 0)
    # the repeats are independent runs, not an ensemble: every one is kept
    cfg = load_train_config(args.task, seed=0, threads=1, **{"keep_members": "all", **parse_settings(args.set)})
    repeats = list(range(args.repeats))
    real = np.arange(ds.states.shape[1])[None, :] < ds.lengths[:, None]
    states = torch.as_tensor(ds.states[real], dtype=torch.float32)  # every real instance, (N, d)
    start = time.perf_counter()
    run = fit(ds, args.arch, cfg, members=len(repeats), split_mode="per_member",
                             progress=False, offsets=repeats)
    print(f"# {args.task} {args.arch}, 5000 bags (data seed 0), repeats {repeats}, relu_bias {cfg.relu_bias}, "
          f"settings {parse_settings(args.set)}; {time.perf_counter() - start:.0f} s")
    config = model_config(args.arch, ds.task, ds.state_size, dropout=cfg.dropout, hidden_size=cfg.hidden_size)
    for m, r in enumerate(repeats):
        fresh = init_ensemble(config, [r])  # repeat r's initial weights, as training started
        initialise(fresh, cfg)
        trained = run.model.member(m)
        fresh.input_shift.copy_(trained.input_shift[None])  # its training split's normalisation
        fresh.input_scale.copy_(trained.input_scale[None])
        at_init = active_fractions(fresh.member(0), states)
        at_end = active_fractions(trained, states)
        test = run.member_test[m]
        dead = " DEAD UNIT" if at_end.min() == 0 else ""
        print(f"repeat {r}: test return {test['return_mse']:.3f} reward {test['reward_mse']:.4f} "
              f"(best epoch {run.train.best_epochs[m]}/{run.train.epochs_run}); units active at init "
              f"{np.array2string(at_init, precision=3)}, at the end {np.array2string(at_end, precision=3)}{dead}",
              flush=True)


if __name__ == "__main__":
    main()
