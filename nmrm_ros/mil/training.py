"""Mini-batch MIL training: Adam on the MSE of bag returns, early stopping on validation return
MSE, best weights kept.

Unlike the paper (one bag per step), bags are trained in padded mini-batches; the loss is computed
on returns divided by `return_scale` (Lunar Lander: 100), as the paper scaled its targets.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml

from ..datasets.trajectories import TrajectoryDataset
from .data import BagTensors, normalisation
from .models import MILRewardModel

CONFIG_FILE = Path(__file__).resolve().parents[2] / "config" / "mil_training.yaml"


@dataclass
class TrainConfig:
    """Hyperparameters of one training run (per task defaults in config/mil_training.yaml)."""

    lr: float = 5e-4
    weight_decay: float = 0.0
    dropout: float = 0.0
    patience: int = 50
    max_epochs: int = 250
    batch_size: int = 64
    return_scale: float = 1.0
    normalisation: str = "standard"
    seed: int = 0
    threads: int = 1

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class TrainResult:
    best_epoch: int
    best_val_return_mse: float
    epochs_run: int
    seconds: float
    history: list = field(default_factory=list)  # per epoch: {"epoch", "train_loss", "val_return_mse"}


def load_train_config(task: str, path: str | Path | None = None, **overrides) -> TrainConfig:
    """The task's hyperparameters from the YAML config (its `defaults` merged with the task's
    entry), then `overrides` (None values ignored)."""
    with open(path or _config_path()) as f:
        table = yaml.safe_load(f)
    if task not in table:
        known = ", ".join(k for k in table if k != "defaults")
        raise ValueError(f"no training config for {task!r} in {path or _config_path()}; known: {known}")
    values = dict(table.get("defaults", {}), **table[task])
    values.update({k: v for k, v in overrides.items() if v is not None})
    unknown = set(values) - set(TrainConfig.__dataclass_fields__)
    if unknown:
        raise ValueError(f"unknown training settings {sorted(unknown)}")
    return TrainConfig(**values)


def _config_path() -> Path:
    """config/mil_training.yaml of the source tree, else of the installed share directory."""
    if CONFIG_FILE.is_file():
        return CONFIG_FILE
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("nmrm_ros")) / "config" / "mil_training.yaml"


def fit_normalisation(model: MILRewardModel, train: TrajectoryDataset, cfg: TrainConfig) -> None:
    """Set the model's input normalisation from the training split only."""
    shift, scale = normalisation(train, cfg.normalisation)
    model.set_normalisation(torch.as_tensor(shift), torch.as_tensor(scale), cfg.return_scale)


@torch.no_grad()
def return_mse(model: MILRewardModel, bags: BagTensors, batch_size: int = 512,
               scaled: bool = False) -> float:
    """Mean squared error of the predicted returns (in label units, or / return_scale)."""
    model.eval()
    total, n = 0.0, len(bags)
    for start in range(0, n, batch_size):
        index = torch.arange(start, min(start + batch_size, n))
        x, lengths, returns = bags.batch(index)
        err = model(x, lengths).returns - returns
        if scaled:
            err = err / model.return_scale
        total += float((err ** 2).sum())
    return total / max(n, 1)


def train_model(model: MILRewardModel, train: TrajectoryDataset, val: TrajectoryDataset,
                cfg: TrainConfig, progress: bool = True) -> TrainResult:
    """Train in place (normalisation from `train`); on return the model holds the best weights."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    fit_normalisation(model, train, cfg)
    train_bags, val_bags = BagTensors(train), BagTensors(val)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    generator = torch.Generator().manual_seed(cfg.seed)
    scale = float(cfg.return_scale)
    best = (float("inf"), -1, copy.deepcopy(model.state_dict()))
    history = []
    start = time.perf_counter()
    bar = _progress(cfg.max_epochs, progress)
    epoch = 0
    for epoch in range(1, cfg.max_epochs + 1):
        model.train()
        order = torch.randperm(len(train_bags), generator=generator)
        losses = []
        for i in range(0, len(order), cfg.batch_size):
            x, lengths, returns = train_bags.batch(order[i:i + cfg.batch_size])
            pred = model(x, lengths).returns
            loss = torch.mean(((pred - returns) / scale) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(float(loss.detach()))
        val_mse = return_mse(model, val_bags)
        history.append({"epoch": epoch, "train_loss": float(np.mean(losses)), "val_return_mse": val_mse})
        if val_mse < best[0]:
            best = (val_mse, epoch, copy.deepcopy(model.state_dict()))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(val_mse=f"{val_mse:.4f}", best=f"{best[0]:.4f}@{best[1]}")
        if epoch - best[1] >= cfg.patience:
            break
    if bar is not None:
        bar.close()
    model.load_state_dict(best[2])
    model.eval()
    return TrainResult(best[1], best[0], epoch, time.perf_counter() - start, history)


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="epochs", unit="ep", leave=False)
