"""Retraining on the labels collected so far: one warm-started ensemble, one versioned checkpoint.

The trainer node runs this in a child process (`python -m nmrm_ros.mil.retrain ...`), so that
training never blocks the node's topics. The split suits a handful of labels: every fifth bag
(in a seeded order; at least one) validates, the rest train, and each member trains on its own
bootstrap resample of them (comparisons: on all of them, from its own seed) (the members' disagreement is then a useful uncertainty for choosing
what to ask a person next). There is no test split: every label is precious, and the person's
labels are what the model is checked against.

Warm start: from `init` (the previous version, or a starting checkpoint) when it is an ensemble
of the same architecture, size and member count, else a fresh one (and the result says so). A
warm-started ensemble keeps serving the member `init` served: each member continues its
predecessor, so the served hidden state keeps the meaning an agent learnt on. Switching to another
member's hidden units (a fresh model: the best on validation) left an agent's policy arbitrary:
in Charger's loop (data seed 31) the switch from member 0 to 1 at the last swap took the agent
from 36.4 to 0 per episode for 40 episodes despite the catch-up; with model 0's member kept
throughout, 36.5 before and 36.7 after (docs/guide/loop.md, `bench/loop_swaps.py`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..datasets.trajectories import TrajectoryDataset
from .checkpoint import CheckpointError, DataInfo, DataSource, EnsembleInfo, load_checkpoint
from .ensemble import MILEnsemble, init_ensemble
from .evaluation import evaluate
from .pipeline import in_step_units
from .run import Run
from .training import load_train_config, train_ensemble


def retrain_splits(n: int, members: int, seed: int, bootstrap: bool = True) -> list:
    """K (train, validation) index pairs: one validation fifth (>= 1 bag), members' training sets
    bootstrapped from the rest (seed + m; bootstrap=False: the rest, for every member). Needs n >= 2."""
    if n < 2:
        raise ValueError(f"retraining needs at least 2 labelled episodes, got {n}")
    order = np.random.default_rng(seed).permutation(n)
    n_val = max(1, n // 5)
    val, train = np.sort(order[:n_val]), np.sort(order[n_val:])
    if not bootstrap:
        return [(train, val)] * members
    return [(np.sort(np.random.default_rng(seed + m).choice(train, len(train))), val)
            for m in range(members)]


def _warm_start(init: str | None, task: str, config, members: int) -> tuple[MILEnsemble | None, str, int | None]:
    """(the ensemble to continue or None, how training starts, the member to keep serving or
    None: the best on validation; one model copied into every member leaves that open)."""
    if not init:
        return None, "fresh (no starting checkpoint)", None
    try:
        model, meta = load_checkpoint(init, task=task)
    except CheckpointError as exc:
        return None, f"not warm-started: {exc}", None
    serving = int(model.serving_member)
    if model.members == 1 and members > 1:  # one model starts every member
        model = MILEnsemble.from_members([model.member(0)] * members)
        serving = None
    same = (model.members == members and model.config.architecture == config.architecture
            and model.config.input_size == config.input_size
            and model.config.hidden_size == config.hidden_size)
    if not same:
        return None, (f"not warm-started: {init} is a {model.members}-member "
                      f"{model.config.architecture}, not a {members}-member {config.architecture}"), None
    units = meta.metrics.get("step_units") or {}
    if "largest_step_reward" in units:  # back to the scale its comparisons reached, where training left it
        from .calibration import Calibration, calibrate

        g = 1.0 / float(units["largest_step_reward"])
        model = calibrate(model, Calibration(np.full(model.members, g), np.zeros(model.members), 0))
    return model.train(), f"warm-started from {init}", serving


def retrain(ds: TrajectoryDataset, out: str | Path, architecture: str = "csc_lstm", members: int = 5,
            max_epochs: int | None = 40, seed: int = 0, init: str | None = None, threads: int = 1,
            feedback: str = "returns", bootstrap: bool | None = None) -> dict:
    """Train a `members`-member ensemble on `ds` from `feedback` (returns | preferences | both;
    warm-started from `init` where it fits), save it to `out` (.pt + .json) and return a summary:
    max_epochs None: the task's training config's; bootstrap: each member trains on its own
    resample of the training bags (default: with returns only; False: all members on all of them).
    labels, comparisons, the validation loss (members' mean) and the ensemble mean's validation
    return MSE (NaN without return labels) and preference accuracy, best epochs, seconds, how it
    started."""
    t0 = time.perf_counter()
    cfg = load_train_config(ds.task, max_epochs=max_epochs, seed=seed, threads=threads, feedback=feedback)
    config = cfg.model_config(architecture, ds.task, ds.state_size)
    # comparisons: no bootstrap of the episodes (a comparison needs both of its episodes, so a
    # resample would drop about 60% of them); the members differ by their seeds
    if bootstrap is None:
        bootstrap = feedback == "returns"
    splits = retrain_splits(len(ds), members, seed, bootstrap=bootstrap)
    ens, start, kept_serving = _warm_start(init, ds.task, config, members)
    seeds = [seed + m for m in range(members)]
    fresh = ens is None
    if fresh:
        ens = init_ensemble(config, seeds)
    result = train_ensemble(ens, ds, splits, cfg, seeds=seeds, progress=False, fresh=fresh)
    val = splits[0][1]
    member_val = list(result.best_val_loss)
    # the member it continues (module docstring), else the best on the validation criterion
    serving = int(np.argmin(member_val)) if kept_serving is None else kept_serving
    ens.serving_member.fill_(serving)
    ens, units = in_step_units(ens, ds, feedback)
    val_metrics = evaluate(ens, ds.subset(val))
    summary = {"labels": int(np.isfinite(ds.returns).sum()), "episodes": len(ds),
               "comparisons": 0 if ds.preferences is None else len(ds.preferences), "feedback": feedback,
               "validation_bags": len(val), "val_loss": float(np.mean(member_val)),
               "val_return_mse": val_metrics["return_mse"],
               "val_preference_accuracy": val_metrics["preference_accuracy"],
               "val_return_std": val_metrics.get("return_std", 0.0), "best_epochs": result.best_epochs,
               "epochs_run": result.epochs_run, "start": start, "serving_member": serving,
               "serving": "the member it continues" if kept_serving is not None else "the best on validation",
               "seconds": round(time.perf_counter() - t0, 2)}
    run = Run.of(
        ens, ds.task, train=result, seed=seed, split_seed=seed, train_config=cfg.to_dict(),
        data=DataInfo(DataSource("live"), len(ds), ds.meta),
        ensemble=EnsembleInfo(members, serving, seeds, [seed] * members,
                              "bootstrap" if feedback == "returns" else "shared"),
        metrics={"val": val_metrics, "member_val_loss": member_val, **summary, **units})
    path = run.save(out)
    summary["checkpoint"] = str(path)
    return summary


def main(argv: list | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nmrm_ros.mil.retrain", description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, help="TrajectoryDataset .npz of the labelled episodes")
    parser.add_argument("--out", required=True, help="checkpoint path (without suffix)")
    parser.add_argument("--architecture", default="csc_lstm")
    parser.add_argument("--members", type=int, default=5)
    parser.add_argument("--max-epochs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--init", default=None, help="checkpoint to warm-start from")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--feedback", default="returns", help="returns | preferences | both")
    a = parser.parse_args(argv)
    try:
        ds = TrajectoryDataset.load(a.dataset)
        summary = retrain(ds, a.out, a.architecture, a.members, a.max_epochs, a.seed, a.init, a.threads,
                          a.feedback)
    except (ValueError, OSError) as exc:
        print(json.dumps({"error": f"{type(exc).__name__}: {exc}"}))
        return 1
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    torch.set_num_threads(1)
    sys.exit(main())
