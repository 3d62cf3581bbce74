"""An image encoder of your own, frozen, for a task spec's `encoder=` (docs/guide/images.md).

    python examples/frozen_encoder.py runs/minigrid_frozen/encoder.pt      # writes its weights (seed 0)
    PYTHONPATH=examples nmrm dataset screen --task \
        "minigrid_corners:make_env,max_steps=60,privileged=pose,encoder=frozen_encoder:Encoder,encoder_weights=$PWD/runs/minigrid_frozen/encoder.pt" \
        --oracle minigrid_corners:oracle --n 1000 --pool-size 3000 --out runs/minigrid_frozen/data_s0.npz

It stands in for an encoder trained elsewhere: a convolution of 8 channels with 6 x 6 kernels and
stride 6, a ReLU, and an average over 4 x 4 cells of the image: 128 features of a 48 x 48 RGB
image (any size works). Its weights are random (seed 0) and never trained.
"""

from __future__ import annotations

import sys

import torch
from torch import nn


class Encoder(nn.Module):
    """(N, 3, H, W) images in 0..1 -> (N, 128) features."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 8, kernel_size=6, stride=6)
        self.pool = nn.AdaptiveAvgPool2d(4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.pool(torch.relu(self.conv(x))).flatten(1)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python examples/frozen_encoder.py WEIGHTS.pt")
    torch.manual_seed(0)
    from pathlib import Path

    out = Path(sys.argv[1])
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(Encoder().state_dict(), out)
    print(f"wrote {out}")
