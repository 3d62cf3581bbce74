"""SAC (stable-baselines3) with separate learning rates for the actor and the critics.

App. E of the paper trains Lunar Lander's value networks with Adam at 1e-3 and the policy at 1e-4;
SB3's `SAC` applies one learning-rate schedule to every optimiser. `SplitLRSAC` overrides only
that step: the actor's optimiser gets `policy_learning_rate`, the others SB3's schedule.

`bound_values` (on by default): the target critics' values are clipped to the highest soft value
the rewards in the replay buffer allow (`nmrm_ros.rl.value_bound`, with SAC's entropy bonus), so
the bootstrapped target cannot run away, as DQN's (`double_dqn`). A value below the bound is left
as it is.
"""

from __future__ import annotations

import math

import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.utils import update_learning_rate

from .overlapped_training import OverlappedTraining
from .value_bound import ValueBound, buffer_rewards


class BoundedCritic(th.nn.Module):
    """A critic whose Q-values are clipped to at most `high` (None: as they are); the same
    parameters as the critic it wraps (Polyak updates reach them unchanged)."""

    def __init__(self, critic: th.nn.Module) -> None:
        super().__init__()
        self.critic = critic
        self.high: float | None = None
        self.clipped = 0

    def forward(self, obs, actions) -> tuple:
        qs = self.critic(obs, actions)
        if self.high is None:
            return qs
        out = tuple(q.clamp(max=self.high) for q in qs)
        self.clipped += sum(int((a != b).sum()) for a, b in zip(out, qs))
        return out


class SplitLRSAC(OverlappedTraining, SAC):
    """SB3 SAC; `policy_learning_rate` (float) is the actor's Adam learning rate; `bound_values`:
    clip the target critics to the value bound (module docstring; `value_bound` is the last one);
    `overlap_training`: see `overlapped_training`."""

    def __init__(self, *args, policy_learning_rate: float = 1e-4, bound_values: bool = True, **kwargs) -> None:
        self.policy_learning_rate = float(policy_learning_rate)
        self.bound_values = bound_values
        self.value_bound: ValueBound | None = None
        super().__init__(*args, **kwargs)

    def _create_aliases(self) -> None:
        super()._create_aliases()
        self.critic_target = BoundedCritic(self.policy.critic_target)

    @property
    def targets_clipped(self) -> int:
        return self.critic_target.clipped

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if self._defer_train(gradient_steps, batch_size):
            return
        if self.bound_values:
            if self.ent_coef_optimizer is not None:  # a learnt alpha: its value now
                alpha = float(th.exp(self.log_ent_coef.detach()))
            else:
                alpha = float(self.ent_coef_tensor)
            bonus = alpha * self.action_space.shape[0] * math.log(2.0)  # alpha * the largest entropy
            self.value_bound = ValueBound.of(buffer_rewards(self.replay_buffer), self.gamma, bonus)
            self.critic_target.high = self.value_bound.high
        super().train(gradient_steps, batch_size)
        if self.value_bound is not None:
            self.logger.record("train/value_bound", self.value_bound.high)
            self.logger.record("train/targets_clipped", self.targets_clipped)

    def _excluded_save_params(self) -> list:
        return super()._excluded_save_params() + ["value_bound"]

    def _update_learning_rate(self, optimizers) -> None:
        super()._update_learning_rate(optimizers)
        update_learning_rate(self.actor.optimizer, self.policy_learning_rate)
        self.logger.record("train/policy_learning_rate", self.policy_learning_rate)
