"""From a `TrajectoryDataset` to model inputs: seeded splits, normalisation, padded batches."""

from __future__ import annotations

import numpy as np
import torch

from ..datasets.trajectories import TrajectoryDataset


def split_indices(n: int, seed: int, fractions=(0.8, 0.1, 0.1)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A seeded random split of range(n) into train/validation/test index arrays."""
    order = np.random.default_rng(seed).permutation(n)
    n_train = int(round(fractions[0] * n))
    n_val = int(round(fractions[1] * n))
    return order[:n_train], order[n_train:n_train + n_val], order[n_train + n_val:]


def normalisation(ds: TrajectoryDataset, kind: str = "standard") -> tuple[np.ndarray, np.ndarray]:
    """(shift, scale) per feature from the real (unpadded) instances of `ds`.

    standard: (mean, std); minmax: x -> (x - min) / (max - min) - 0.5, i.e. shift = (min + max) / 2,
    scale = max - min. A constant feature gets scale 1.
    """
    mask = np.arange(ds.states.shape[1])[None, :] < ds.lengths[:, None]
    x = ds.states[mask].astype(np.float64)
    if kind == "standard":
        shift, scale = x.mean(axis=0), x.std(axis=0)
    elif kind == "minmax":
        lo, hi = x.min(axis=0), x.max(axis=0)
        shift, scale = (lo + hi) / 2.0, hi - lo
    else:
        raise ValueError(f"unknown normalisation {kind!r}: use 'standard' or 'minmax'")
    scale = np.where(scale > 1e-12, scale, 1.0)
    return shift, scale


class BagTensors:
    """A dataset's bags as tensors: x (n, L, d) float32, lengths (n,), returns (n,), rewards (n, L)."""

    def __init__(self, ds: TrajectoryDataset) -> None:
        self.x = torch.as_tensor(np.ascontiguousarray(ds.states, dtype=np.float32))
        self.lengths = torch.as_tensor(ds.lengths, dtype=torch.int64)
        self.returns = torch.as_tensor(ds.returns, dtype=torch.float32)
        self.rewards = torch.as_tensor(ds.rewards, dtype=torch.float32)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def batch(self, index: torch.Tensor, label_index: torch.Tensor | None = None):
        """x, lengths, returns of the bags at `index`, trimmed to the batch's longest bag; the
        returns are those of the bags at `label_index` if given (swapped labels)."""
        lengths = self.lengths[index]
        horizon = int(lengths.max())
        labels = self.returns[index if label_index is None else label_index]
        return self.x[index, :horizon], lengths, labels
