"""SAC (stable-baselines3) with separate learning rates for the actor and the critics.

App. E of the paper trains Lunar Lander's value networks with Adam at 1e-3 and the policy at 1e-4;
SB3's `SAC` applies one learning-rate schedule to every optimiser. `SplitLRSAC` overrides only
that step: the actor's optimiser gets `policy_learning_rate`, the others SB3's schedule.
"""

from __future__ import annotations

from stable_baselines3 import SAC
from stable_baselines3.common.utils import update_learning_rate

from .overlapped_training import OverlappedTraining


class SplitLRSAC(OverlappedTraining, SAC):
    """SB3 SAC; `policy_learning_rate` (float) is the actor's Adam learning rate;
    `overlap_training`: see `overlapped_training`."""

    def __init__(self, *args, policy_learning_rate: float = 1e-4, **kwargs) -> None:
        self.policy_learning_rate = float(policy_learning_rate)
        super().__init__(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if self._defer_train(gradient_steps, batch_size):
            return
        super().train(gradient_steps, batch_size)

    def _update_learning_rate(self, optimizers) -> None:
        super()._update_learning_rate(optimizers)
        update_learning_rate(self.actor.optimizer, self.policy_learning_rate)
        self.logger.record("train/policy_learning_rate", self.policy_learning_rate)
