"""One training run end to end: split a dataset, train, evaluate on the test split, checkpoint."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..datasets.trajectories import TrajectoryDataset
from .checkpoint import save_checkpoint
from .data import split_indices
from .evaluation import evaluate
from .models import MILRewardModel, build_model, model_config
from .training import TrainConfig, TrainResult, train_model


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
    model = build_model(model_config(architecture, ds.task, ds.state_size, dropout=cfg.dropout))
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
