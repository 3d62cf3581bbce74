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
    pixels), lengths (n,), returns (n,), rewards (n, L).

    patch_layout: a model's (image_shape, patch) (`MILEnsemble.patch_layout`): the image values
    of every state are stored, once, in the order its image encoder reads them (patch after
    patch, `image_encoder.patches`), so that a batch's pixels reach the encoder without a strided
    copy a step (`patch_ordered`: give the model `patch_ordered=True` with them); None: the
    states as they are."""

    def __init__(self, ds: TrajectoryDataset, patch_layout: tuple | None = None) -> None:
        states = ds.states if ds.states.dtype == np.uint8 else np.ascontiguousarray(ds.states, dtype=np.float32)
        self.patch_ordered = patch_layout is not None
        if self.patch_ordered:
            states = _in_patch_order(torch.as_tensor(states), *patch_layout)
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
        index = torch.as_tensor(index, dtype=torch.int64)
        lengths = self.lengths[index]
        horizon = int(lengths.max())
        labels = self.returns[index if label_index is None else label_index]
        # index_select copies whole rows (~6x faster than x[index] on uint8 pixels)
        x = torch.index_select(self.x[:, :horizon], 0, index.reshape(-1))
        return x.view(*index.shape, *x.shape[1:]), lengths, labels


def _in_patch_order(states: torch.Tensor, image_shape: tuple, patch: int, rows: int = 256) -> torch.Tensor:
    """A copy of states (n, L, d) whose image values (the first H*W*C) are in the order
    `image_encoder.patches` reads them, the rest as they are; `rows` bags at a time."""
    from .image_encoder import patch_grid

    values = int(np.prod(image_shape))
    out = torch.empty_like(states)
    for start in range(0, len(states), rows):
        part = states[start:start + rows]
        n, length = part.shape[:2]
        out[start:start + rows, :, :values].view(n, length, -1).copy_(
            patch_grid(part[..., :values], image_shape, patch).reshape(n, length, -1))
        out[start:start + rows, :, values:] = part[..., values:]
    return out
