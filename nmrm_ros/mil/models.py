"""The four MIL reward-model architectures of the paper (Sec. 3.2, App. C.2, D.3, D.4).

Every model maps a batch of padded bags (trajectories) to per-step rewards, per-step hidden
states and bag returns:

    out = model(x, lengths)      x: (B, T, d) float32 instances, lengths: (B,) int64
    out.returns (B,)  out.rewards (B, T)  out.hidden (B, T, k)   (zero beyond each length)

`hidden[:, t]` is h'_{t+1}, the LSTM hidden state after instance t (k = 0 for the Instance Space
NN). Inputs are normalised inside the model ((x - input_shift) / input_scale, buffers set from
the training split), and outputs are in the units of the labels (`return_scale` multiplies the
network's output; Lunar Lander trains on returns / 100).

The architectures' rules (what the head sees, how its outputs become rewards and a return) are
defined once, in `architectures.REGISTRY`; this module holds one member's layers.
The LSTM has a learnable initial state (h'_0, c'_0).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch
from torch import nn

from .architectures import REGISTRY, architecture
from .dropout import dropout_mask
from .image_encoder import check_image_config, default_patch, encoded_size, patches, pixel_weights

ARCHITECTURES = tuple(REGISTRY)
ARCHITECTURE_NAMES = {name: arch.title for name, arch in REGISTRY.items()}


@dataclass(frozen=True)
class ModelConfig:
    """Everything needed to rebuild a model (stored in checkpoint metadata).

    fe_sizes: feature extractor layer widths (FC + ReLU + dropout each); head_sizes: head hidden
    widths (FC + ReLU + dropout each) before the final FC to 1; output_activation: one of
    OUTPUT_ACTIVATIONS ("leaky_relu": slope 1e-6, the paper's for Lunar Lander); hidden_size: LSTM
    state size (paper: 2), or the attention width of the transformer. image_shape: (H, W, C) of
    the image whose pixels are the first H*W*C input values (() for a vector state), read by the
    image encoder (`image_encoder`: `patch`-pixel patches, `patch_channels` each) in front of the
    feature extractor.
    """

    architecture: str
    input_size: int
    fe_sizes: tuple = (64, 32, 32)
    head_sizes: tuple = (32, 16)
    hidden_size: int = 2
    dropout: float = 0.0
    output_activation: str = "none"
    image_shape: tuple = ()
    patch: int = 4
    patch_channels: int = 8

    @property
    def image_values(self) -> int:
        """How many leading inputs are pixels (0: no image)."""
        return int(math.prod(self.image_shape)) if self.image_shape else 0

    @property
    def encoded_size(self) -> int:
        """The feature extractor's input size (the image encoder's output and the vector part)."""
        if not self.image_shape:
            return self.input_size
        return encoded_size(self.image_shape, self.patch, self.patch_channels, self.input_size)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["fe_sizes"], d["head_sizes"] = list(self.fe_sizes), list(self.head_sizes)
        d["image_shape"] = list(self.image_shape)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        d = dict(d)
        d["fe_sizes"], d["head_sizes"] = tuple(d["fe_sizes"]), tuple(d["head_sizes"])
        d["image_shape"] = tuple(d.get("image_shape", ()))
        return cls(**d)


#: What the head's last FC output goes through: "none"; "leaky_relu" (negative slope 1e-6: the
#: paper's Lunar Lander models, whose rewards are non-negative); "softplus" (log(1 + e^z):
#: non-negative too, with a gradient that never vanishes as the leaky ReLU's 1e-6 does; the paper
#: (App. F) finds the models stuck on its return plateau to be the ones paying negative rewards).
OUTPUT_ACTIVATIONS = ("none", "leaky_relu", "softplus")


def output_activation(name: str, z: torch.Tensor) -> torch.Tensor:
    """The head's output activation `name` (OUTPUT_ACTIVATIONS) applied to z."""
    if name == "leaky_relu":
        return torch.nn.functional.leaky_relu(z, 1e-6)
    if name == "softplus":
        return torch.nn.functional.softplus(z)
    return z


#: Layer sizes per task family (paper tables). Toy: FE 2->2, HN 2->1, no dropout.
FAMILY_SIZES = {
    "toy": {"fe_sizes": (2,), "head_sizes": (), "output_activation": "none"},
    "navigation": {"fe_sizes": (64, 32, 32), "head_sizes": (32, 16), "output_activation": "none"},
    "lunar_lander": {"fe_sizes": (128, 64, 64), "head_sizes": (64, 32),
                     "output_activation": "leaky_relu"},
}


class MILOutput(NamedTuple):
    returns: torch.Tensor  # (B,)
    rewards: torch.Tensor  # (B, T)
    hidden: torch.Tensor  # (B, T, k)


class FastDropout(nn.Module):
    """Inverted dropout (as nn.Dropout) with the mask from `dropout_mask`."""

    def __init__(self, p: float) -> None:
        super().__init__()
        self.p = float(p)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0.0:
            return x
        return x * dropout_mask(x, self.p)


def _mlp(sizes: list, dropout: float, final_linear: bool) -> nn.Sequential:
    """FC + ReLU + Dropout for each consecutive pair of sizes; the last one plain FC if
    final_linear."""
    layers: list = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if final_linear and i == len(sizes) - 2:
            break
        layers.append(nn.ReLU())
        if dropout > 0:
            layers.append(FastDropout(dropout))
    return nn.Sequential(*layers)


class CausalAttention(nn.Module):
    """One causal self-attention layer over a bag's features (the transformer architecture,
    `architectures.CausalTransformer`): (B, T, F) -> z (B, T, k), z_t seeing f_0..f_t only."""

    def __init__(self, feature_size: int, width: int) -> None:
        super().__init__()
        self.inp = nn.Linear(feature_size, width)
        self.query = nn.Linear(width, width, bias=False)
        self.key = nn.Linear(width, width, bias=False)
        self.value = nn.Linear(width, width, bias=False)
        self.out = nn.Linear(width, width)

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        from .architectures import time_code

        t, k = f.shape[1], self.inp.out_features
        x = self.inp(f) + torch.as_tensor(time_code(t, k), dtype=f.dtype)
        scores = self.query(x) @ self.key(x).transpose(1, 2) / k ** 0.5  # (B, T, T)
        scores = scores.masked_fill(torch.ones(t, t, dtype=torch.bool).triu(1), float("-inf"))
        return torch.tanh(x + self.out(torch.softmax(scores, dim=-1) @ self.value(x)))


class MILRewardModel(nn.Module):
    """One member of any architecture: normalisation buffers, feature extractor, [LSTM,] head;
    the architecture's rule from `architectures.REGISTRY`. The package computes with
    `MILEnsemble`s; this is the reference layout of one member (its parameter names are a
    checkpoint's) and the initialisation `init_ensemble` copies."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.rule = architecture(config.architecture)  # what the head sees, its outputs' rule
        self.uses_lstm = self.rule.uses_lstm
        self.uses_attention = self.rule.uses_attention
        self.register_buffer("input_shift", torch.zeros(config.input_size))
        self.register_buffer("input_scale", torch.ones(config.input_size))
        self.register_buffer("return_scale", torch.ones(()))
        if config.image_shape:
            check_image_config(config.image_shape, config.patch, config.patch_channels, config.input_size)
            h, w, c = config.image_shape
            self.encoder = nn.Linear(config.patch * config.patch * c, config.patch_channels)
        self.feature_extractor = _mlp([config.encoded_size, *config.fe_sizes], config.dropout, False)
        self.feature_size = config.fe_sizes[-1]
        if self.uses_lstm:
            self.lstm = nn.LSTM(self.feature_size, config.hidden_size, batch_first=True)
            self.h0 = nn.Parameter(torch.zeros(config.hidden_size))
            self.c0 = nn.Parameter(torch.zeros(config.hidden_size))
        if self.uses_attention:
            self.attention = CausalAttention(self.feature_size, config.hidden_size)
        self.head = _mlp([self.head_input_size, *config.head_sizes, 1], config.dropout, True)

    @property
    def head_input_size(self) -> int:
        return self.rule.head_input_size(self.feature_size, self.config.hidden_size)

    @property
    def hidden_size(self) -> int:
        return self.config.hidden_size if self.uses_lstm or self.uses_attention else 0

    def set_normalisation(self, shift: torch.Tensor, scale: torch.Tensor,
                          return_scale: float = 1.0) -> None:
        """Set the input normalisation (computed on the training split; an image's pixels:
        `image_encoder.IMAGE_SHIFT`) and the label scale."""
        self.input_shift.copy_(torch.as_tensor(shift, dtype=torch.float32))
        self.input_scale.copy_(torch.as_tensor(scale, dtype=torch.float32))
        self.return_scale.fill_(float(return_scale))

    def _features(self, x: torch.Tensor) -> torch.Tensor:
        values = self.config.image_values
        z = (x[..., values:].float() - self.input_shift[values:]) / self.input_scale[values:]
        if values:
            p = patches(x[..., :values], self.config.image_shape, self.config.patch).float()
            e = torch.relu(torch.nn.functional.linear(p, *pixel_weights(self.encoder.weight, self.encoder.bias)))
            z = torch.cat([e.flatten(-2), z], dim=-1)
        return self.feature_extractor(z)

    def _head(self, z: torch.Tensor) -> torch.Tensor:
        return output_activation(self.config.output_activation, self.head(z)).squeeze(-1) * self.return_scale

    def _lstm(self, f: torch.Tensor) -> torch.Tensor:
        b = f.shape[0]
        h0 = self.h0.expand(1, b, -1).contiguous()
        c0 = self.c0.expand(1, b, -1).contiguous()
        out, _ = self.lstm(f, (h0, c0))
        return out

    def forward(self, x: torch.Tensor, lengths: torch.Tensor) -> MILOutput:
        mask = (torch.arange(x.shape[1], device=x.device)[None, :] < lengths[:, None]).float()
        features = self._features(x)
        hidden = (self._lstm(features) if self.uses_lstm
                  else self.attention(features) if self.uses_attention else None)
        y = self._head(self.rule.head_input(features, hidden))
        returns, rewards = self.rule.outputs(y, mask, lengths)
        if hidden is None:
            return MILOutput(returns, rewards, mask.new_zeros(x.shape[0], x.shape[1], 0))
        return MILOutput(returns, rewards, hidden * mask[..., None])


def family_of(task: str) -> str:
    """The layer-size family of a task (its TaskInfo's) or a toy dataset ("toy")."""
    from ..tasks import TASKS, task_info

    return task_info(task).family if task in TASKS else "toy"  # a user's task: its config's widths, else toy


def model_config(architecture: str, task: str, input_size: int, dropout: float = 0.0,
                 hidden_size: int = 2, output_activation: str | None = None,
                 fe_sizes=None, head_sizes=None) -> ModelConfig:
    """The paper's configuration of `architecture` for `task`'s family (output_activation: None or
    "" for the family's; fe_sizes / head_sizes: layer widths, None for the family's); an image
    task's states get the image encoder (`image_encoder`)."""
    if architecture not in REGISTRY:
        raise ValueError(f"unknown architecture {architecture!r}; known: {', '.join(REGISTRY)}")
    sizes = dict(FAMILY_SIZES[family_of(task)])
    if fe_sizes is not None:
        sizes["fe_sizes"] = tuple(int(w) for w in fe_sizes)
    if head_sizes is not None:
        sizes["head_sizes"] = tuple(int(w) for w in head_sizes)
    if output_activation:
        if output_activation not in OUTPUT_ACTIVATIONS:
            raise ValueError(f"unknown output activation {output_activation!r}; use one of "
                             f"{', '.join(OUTPUT_ACTIVATIONS)}")
        sizes["output_activation"] = output_activation
    hidden_size = max(int(hidden_size), REGISTRY[architecture].min_hidden_size)
    image_shape = image_shape_of(task)
    if image_shape:
        sizes["patch"] = default_patch(*image_shape[:2])
        check_image_config(image_shape, sizes["patch"], 8, int(input_size))
    return ModelConfig(architecture=architecture, input_size=input_size, hidden_size=hidden_size,
                       dropout=dropout, image_shape=image_shape, **sizes)


def image_shape_of(task: str) -> tuple:
    """(H, W, C) of the image in `task`'s states (its TaskInfo's), () for a vector state or a toy
    dataset."""
    from ..tasks import TASKS, task_info
    from ..tasks.gym_task import is_task_spec

    return tuple(task_info(task).image_shape) if task in TASKS or is_task_spec(task) else ()


def build_model(config: ModelConfig) -> MILRewardModel:
    """One freshly initialised member of `config` (ValueError for an unknown architecture)."""
    return MILRewardModel(config)
