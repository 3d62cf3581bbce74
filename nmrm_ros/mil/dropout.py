"""Dropout for the MIL models: masks from fast 16-bit draws, one stream per ensemble member, and
ReLU + dropout as one autograd step.

    masks = MemberDropout(p=0.1, seeds=[0, 1, 2], widths=[64, 32, 32, 32, 16])
    layer_masks = masks.take(bags=32, steps=[100, 100, 100])   # one (K, 32 * 100, F) per width
    z = relu_dropout(z, layer_masks[0], 1 / 0.9)

A mask is 1 / (1 - p) with probability 1 - p, else 0: four 16-bit uniform draws are cut from each
64-bit word of numpy's SFC64 generator (p is resolved to 1/65536). On CPU this is ~4x faster than
`torch.randint` words and ~8x faster than `bernoulli_`.
"""

from __future__ import annotations

import numpy as np
import torch


def _threshold(p: float) -> int:
    """The int16 value a uniform 16-bit draw must reach to be kept (probability 1 - p)."""
    return int(round(p * 65536)) - 32768


def dropout_mask(like: torch.Tensor, p: float) -> torch.Tensor:
    """Inverted-dropout mask shaped like `like`, seeded by one draw from torch's generator (so
    `torch.manual_seed` still fixes every mask)."""
    n = like.numel()
    seed = int(torch.randint(0, 2 ** 62, (1,)))
    words = np.random.SFC64(seed).random_raw((n + 3) // 4)
    uniform16 = torch.from_numpy(words.view(np.int16)[:n]).view(like.shape)
    mask = torch.empty(like.shape, dtype=like.dtype)
    torch.ge(uniform16, _threshold(p), out=mask)  # written as 0/1 floats: no bool tensor, no where
    return mask.mul_(1.0 / (1.0 - p))


class MemberDropout:
    """The dropout masks of an ensemble's K members for one training step: member k's masks come
    from its own SFC64 stream (seeded by `seeds[k]`) and cover only its own (bags, steps[k], F)
    instances, so that they do not depend on the other members: a member of a 10-member run trains
    as it would alone.

    Each step takes one mask per layer width in `widths` (the order of the forward pass). Member k
    draws, for each layer in turn, ceil(bags * steps[k] * F / 4) words; padding beyond steps[k] is
    1 / (1 - p). The masks are written into buffers kept from step to step (fresh multi-megabyte
    allocations cost page faults): a step's masks are valid until the next `take`, which is
    enough for `relu_dropout`, whose backward does not need them.
    """

    def __init__(self, p: float, seeds: list, widths: list) -> None:
        self.p = float(p)
        self.widths = [int(w) for w in widths]
        self.streams = [np.random.SFC64(np.random.SeedSequence([int(s), 0xD80])) for s in seeds]
        self._buffers: tuple = ((), [])  # (members, bags, horizon), one (K, bags, horizon, F) tensor per width

    @property
    def members(self) -> int:
        return len(self.streams)

    def take(self, bags: int, steps: list, members: torch.Tensor | None = None) -> list:
        """This step's masks: one float32 tensor (K, bags * max(steps), F) per layer width; with
        `members` (indices, K') only those members' streams draw, for their K' step counts."""
        streams = self.streams if members is None else [self.streams[int(m)] for m in members]
        K, horizon = len(streams), max(steps, default=0)
        if len(steps) != K:
            raise ValueError(f"{K} members need {K} step counts, got {len(steps)}")
        if self._buffers[0] != (K, bags, horizon):
            self._buffers = ((K, bags, horizon), [torch.empty(K, bags, horizon, w) for w in self.widths])
        masks = self._buffers[1]
        threshold = _threshold(self.p)
        for k, stream in enumerate(streams):
            t_k = int(steps[k])
            sizes = [bags * t_k * width for width in self.widths]
            words = stream.random_raw(sum((n + 3) // 4 for n in sizes)).view(np.int16)
            start = 0
            for mask, n, width in zip(masks, sizes, self.widths):
                uniform16 = torch.from_numpy(words[start:start + n]).view(bags, t_k, width)
                torch.ge(uniform16, threshold, out=mask[k, :, :t_k])  # 0/1 floats: no bool tensor
                mask[k, :, t_k:] = 1.0
                start += (n + 3) // 4 * 4
        for mask in masks:
            mask.mul_(1.0 / (1.0 - self.p))
        return [mask.view(K, bags * horizon, width) for mask, width in zip(masks, self.widths)]


class _ReLUDropout(torch.autograd.Function):
    """relu(z) * mask, saving only the output: its gradient is grad * scale where the output is
    positive (there z > 0 and the unit was kept, so the mask is exactly `scale`), else 0."""

    @staticmethod
    def forward(ctx, z: torch.Tensor, mask: torch.Tensor, scale: float) -> torch.Tensor:
        out = z.clamp_min(0).mul_(mask)
        ctx.save_for_backward(out)
        ctx.scale = scale
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (out,) = ctx.saved_tensors
        return torch.ops.aten.threshold_backward(grad, out, 0.0).mul_(ctx.scale), None, None


def relu_dropout(z: torch.Tensor, mask: torch.Tensor, scale: float) -> torch.Tensor:
    """relu(z) * mask for an inverted-dropout `mask` with values in {0, scale}."""
    return _ReLUDropout.apply(z, mask, float(scale))
