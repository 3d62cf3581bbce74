"""An agent that sees an image: SB3's features extractor for observations whose first values are
an image's pixels and whose rest is a vector (the served state h', a privileged or vector state).

    model = DoubleDQN("MlpPolicy", env, policy_kwargs={
        "features_extractor_class": ImageStateExtractor,
        "features_extractor_kwargs": {"image_shape": (32, 32, 3)}})

The observation stays one flat float vector (the replay buffer, its relabelling with a new reward
model, the value bound and the kept policy see what they see for a vector state); the extractor
reads its first H*W*C values as an image (0..255, row-major H, W, C, as `TaskInfo.image_shape`
says), puts them through a small CNN — two 3x3 convolutions of stride 2 (16 and 32 channels, ReLU),
then a linear layer to `image_features` (ReLU) — and appends the rest of the observation
unchanged, for the policy's MLP (`net_arch`). SB3's NatureCNN needs images of 36 x 36 or more; the
pixel tasks' are 32 x 32.
"""

from __future__ import annotations

import math

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor


class ImageStateExtractor(BaseFeaturesExtractor):
    """(B, H*W*C + k) -> (B, image_features + k): a CNN of the leading image, then the rest."""

    def __init__(self, observation_space: gym.spaces.Box, image_shape: tuple, image_features: int = 128) -> None:
        h, w, c = (int(v) for v in image_shape)
        pixels = h * w * c
        total = int(observation_space.shape[0])
        if len(observation_space.shape) != 1 or total < pixels:
            raise ValueError(f"an observation of shape {observation_space.shape} does not start with a "
                             f"{h}x{w}x{c} image")
        super().__init__(observation_space, features_dim=image_features + total - pixels)
        self.image_shape, self.pixels = (h, w, c), pixels
        side = (math.ceil(math.ceil(h / 2) / 2), math.ceil(math.ceil(w / 2) / 2))
        self.cnn = torch.nn.Sequential(
            torch.nn.Conv2d(c, 16, 3, stride=2, padding=1), torch.nn.ReLU(),
            torch.nn.Conv2d(16, 32, 3, stride=2, padding=1), torch.nn.ReLU(),
            torch.nn.Flatten(), torch.nn.Linear(32 * side[0] * side[1], image_features), torch.nn.ReLU())

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        h, w, c = self.image_shape
        image = observations[:, :self.pixels].reshape(-1, h, w, c).permute(0, 3, 1, 2) / 255.0
        return torch.cat([self.cnn(image), observations[:, self.pixels:]], dim=1)


def image_policy_kwargs(image_shape: tuple) -> dict:
    """The policy_kwargs that put `ImageStateExtractor` in front of the policy's MLP ({} for a
    vector observation, image_shape ())."""
    if not image_shape:
        return {}
    return {"features_extractor_class": ImageStateExtractor,
            "features_extractor_kwargs": {"image_shape": tuple(int(v) for v in image_shape)}}
