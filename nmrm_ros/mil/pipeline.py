"""Training runs end to end: split a dataset, train one model or an ensemble, evaluate on the test
split(s), checkpoint."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..datasets.trajectories import TrajectoryDataset
from .checkpoint import save_checkpoint
from .data import split_indices
from .ensemble import MILEnsemble, init_ensemble
from .evaluation import evaluate
from .models import MILRewardModel, build_model, model_config
from .training import EnsembleTrainResult, TrainConfig, TrainResult, train_ensemble, train_model

SPLIT_MODES = ("shared", "per_member", "bootstrap")


@dataclass
class RunResult:
    model: MILRewardModel
    train: TrainResult
    test_metrics: dict
    val_metrics: dict
    checkpoint: Path | None


def train_and_evaluate(ds: TrajectoryDataset, architecture: str, cfg: TrainConfig,
                       split_seed: int = 0, out: str | Path | None = None,
                       progress: bool = True, data_source: str = "") -> RunResult:
    """Split `ds` 80/10/10 with `split_seed`, train `architecture` with `cfg` (weights seeded by
    cfg.seed), evaluate on the test split, and save a checkpoint to `out` if given."""
    train, val, test = split_indices(len(ds), split_seed)
    torch.manual_seed(cfg.seed)
    model = build_model(model_config(architecture, ds.task, ds.state_size, dropout=cfg.dropout,
                                     hidden_size=cfg.hidden_size))
    result = train_model(model, ds.subset(train), ds.subset(val), cfg, progress=progress)
    test_metrics = evaluate(model, ds.subset(test))
    val_metrics = evaluate(model, ds.subset(val))
    path = None
    if out is not None:
        path = save_checkpoint(
            model, out, task=ds.task, seed=cfg.seed, split_seed=split_seed,
            train_config=cfg.to_dict(), data={"source": data_source, "n": len(ds),
                                              "meta": ds.meta},
            metrics={"test": test_metrics, "val": val_metrics,
                     "best_epoch": result.best_epoch, "epochs_run": result.epochs_run,
                     "seconds": result.seconds})
    return RunResult(model, result, test_metrics, val_metrics, path)


@dataclass
class EnsembleRunResult:
    ensemble: MILEnsemble
    train: EnsembleTrainResult
    member_test: list  # K dicts of test metrics, each member on its own test split
    member_val: list
    ensemble_test: dict | None  # the ensemble-mean prediction (shared test split only)
    seeds: list
    split_seeds: list
    checkpoint: Path | None


def member_splits(n: int, members: int, split_seed: int, mode: str,
                  offsets: list[int] | None = None) -> tuple[list, list]:
    """(K (train, val, test) index triples, the split seed of each member).

    shared: one 80/10/10 split (split_seed) for all; per_member: member m on split split_seed + m
    (the paper's repeats over splits); bootstrap: one split, each member's training set resampled
    with replacement from it (seed split_seed + m). `offsets` replaces m by offsets[m] (e.g. to
    rerun repeats 1, 3 and 8 of a 10-repeat table exactly)."""
    if mode not in SPLIT_MODES:
        raise ValueError(f"unknown split mode {mode!r}; use one of {', '.join(SPLIT_MODES)}")
    offsets = list(range(members)) if offsets is None else list(offsets)
    if len(offsets) != members:
        raise ValueError(f"{len(offsets)} member offsets for {members} members")
    if mode == "per_member":
        seeds = [split_seed + m for m in offsets]
        return [split_indices(n, s) for s in seeds], seeds
    train, val, test = split_indices(n, split_seed)
    if mode == "shared":
        return [(train, val, test)] * members, [split_seed] * members
    triples = [(np.sort(np.random.default_rng(split_seed + m).choice(train, len(train))), val, test)
               for m in offsets]
    return triples, [split_seed] * members


def train_ensemble_and_evaluate(ds: TrajectoryDataset, architecture: str, cfg: TrainConfig,
                                members: int, split_seed: int = 0, split_mode: str = "shared",
                                out: str | Path | None = None, progress: bool = True,
                                data_source: str = "", on_epoch=None,
                                offsets: list[int] | None = None) -> EnsembleRunResult:
    """Train `members` models of `architecture` as one ensemble (member m: weights and shuffle
    seeded cfg.seed + m, split per `split_mode`; offsets[m] instead of m if given), evaluate each
    on its test split (and the ensemble mean on a shared one), pick the serving member (best
    validation return MSE) and save a checkpoint to `out` if given. on_epoch: see `train_ensemble`."""
    splits, split_seeds = member_splits(len(ds), members, split_seed, split_mode, offsets)
    seeds = [cfg.seed + m for m in (range(members) if offsets is None else offsets)]
    config = model_config(architecture, ds.task, ds.state_size, dropout=cfg.dropout,
                          hidden_size=cfg.hidden_size)
    ens = init_ensemble(config, seeds)
    result = train_ensemble(ens, ds, [(tr, va) for tr, va, _ in splits], cfg, seeds=seeds,
                            progress=progress, on_epoch=on_epoch)
    member_test = [evaluate(ens.member(m), ds.subset(te)) for m, (_, _, te) in enumerate(splits)]
    member_val = [evaluate(ens.member(m), ds.subset(va)) for m, (_, va, _) in enumerate(splits)]
    serving = int(np.argmin(result.best_val_loss))  # the best on the validation criterion
    ens.serving_member.fill_(serving)
    ensemble_test = None
    if split_mode != "per_member":
        ensemble_test = evaluate(ens, ds.subset(splits[0][2]))
    path = None
    if out is not None:
        path = save_checkpoint(
            ens, out, task=ds.task, seed=cfg.seed, split_seed=split_seed,
            train_config=cfg.to_dict(),
            data={"source": data_source, "n": len(ds), "meta": ds.meta},
            ensemble={"members": members, "seeds": seeds, "split_seeds": split_seeds,
                      "split_mode": split_mode, "serving_member": serving},
            metrics={"test": ensemble_test, "member_test": member_test, "member_val": member_val,
                     "best_epochs": result.best_epochs, "still_improving": result.still_improving,
                     "epochs_run": result.epochs_run, "seconds": result.seconds})
    return EnsembleRunResult(ens, result, member_test, member_val, ensemble_test, seeds,
                             split_seeds, path)
