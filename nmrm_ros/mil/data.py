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


def normalisation(ds: TrajectoryDataset, kind: str = "standard",
                  image_values: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(shift, scale) per feature from the real (unpadded) instances of `ds`.

    standard: (mean, std); minmax: x -> (x - min) / (max - min) - 0.5, i.e. shift = (min + max) / 2,
    scale = max - min. A constant feature gets scale 1. The first `image_values` features are an
    image's pixels: shift and scale `image_encoder.IMAGE_SHIFT` (0..255 -> -1..1), whatever `kind`.
    """
    from .image_encoder import IMAGE_SHIFT

    if kind not in ("standard", "minmax"):
        raise ValueError(f"unknown normalisation {kind!r}: use 'standard' or 'minmax'")
    mask = np.arange(ds.states.shape[1])[None, :] < ds.lengths[:, None]
    x = ds.states[..., image_values:][mask].astype(np.float64)
    if kind == "standard":
        shift, scale = x.mean(axis=0), x.std(axis=0)
    else:
        lo, hi = x.min(axis=0), x.max(axis=0)
        shift, scale = (lo + hi) / 2.0, hi - lo
    scale = np.where(scale > 1e-12, scale, 1.0)
    pixels = np.full(image_values, IMAGE_SHIFT)
    return np.concatenate([pixels, shift]), np.concatenate([pixels, scale])


#: at most this many input values in one evaluation batch (all members'): 2^25 float32, 128 MB
EVAL_VALUES = 2 ** 25


class BagTensors:
    """A dataset's bags as tensors: x (n, L, d) float32 (uint8 as stored for an image task's
    pixels), lengths (n,), returns (n,), rewards (n, L)."""

    def __init__(self, ds: TrajectoryDataset) -> None:
        states = ds.states if ds.states.dtype == np.uint8 else np.ascontiguousarray(ds.states, dtype=np.float32)
        self.x = torch.as_tensor(states)
        self.lengths = torch.as_tensor(ds.lengths, dtype=torch.int64)
        self.returns = torch.as_tensor(ds.returns, dtype=torch.float32)
        self.rewards = torch.as_tensor(ds.rewards, dtype=torch.float32)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def eval_rows(self, batch_size: int, members: int = 1) -> int:
        """`batch_size`, or fewer bags where `members` copies of that many bags would hold more
        than `EVAL_VALUES` inputs (image states: ~300 KB a bag)."""
        per_bag = max(1, int(self.x.shape[1]) * int(self.x.shape[2]) * int(members))
        return max(1, min(int(batch_size), EVAL_VALUES // per_bag))

    def batch(self, index: torch.Tensor, label_index: torch.Tensor | None = None):
        """x (float32, or uint8 pixels: the models' image encoder reads them as they are),
        lengths, returns of the bags at `index`, trimmed to the batch's longest bag; the returns
        are those of the bags at `label_index` if given (swapped labels)."""
        lengths = self.lengths[index]
        horizon = int(lengths.max())
        labels = self.returns[index if label_index is None else label_index]
        return self.x[index, :horizon], lengths, labels
