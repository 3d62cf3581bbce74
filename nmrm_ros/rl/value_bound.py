"""What values the rewards allow: the bound on an agent's Q-values.

With per-step rewards r in [r_lo, r_hi] and discount gamma, no policy's discounted return, from
any state and however long it runs, leaves

    [min(r_lo, 0) / (1 - gamma),  max(r_hi, 0) / (1 - gamma)]

(the geometric series; 0 is included because an episode may end at any step). A soft value (SAC)
also holds the entropy bonus alpha * H of each later step; on actions squashed to [-1, 1]^d no
policy's entropy exceeds d log 2 (the uniform one's), so its top is raised by alpha d log 2. A value estimate
beyond it is an artefact of bootstrapping, not something the agent can earn: e.g. rewards in
[0, 1] at gamma 0.99 bound every Q-value by 100. The rewards are the ones the agent has been paid
(its replay buffer: the served reward model's, or the oracle's), so the bound needs no per-task
setting and follows a reward model that is swapped or relabelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ValueBound:
    """low, high: the bound on values; reward_low, reward_high: the rewards it comes from."""

    low: float
    high: float
    reward_low: float
    reward_high: float
    gamma: float

    @classmethod
    def of(cls, rewards: np.ndarray, gamma: float, bonus: float = 0.0) -> "ValueBound":
        """The bound for the rewards seen (any shape; empty: rewards of 0) at discount `gamma` < 1;
        `bonus`: the most a step adds beyond its reward (SAC's entropy bonus), raising the top."""
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"a value bound needs a discount in [0, 1), got {gamma}")
        rewards = np.asarray(rewards, dtype=np.float64)
        lo = float(rewards.min()) if rewards.size else 0.0
        hi = float(rewards.max()) if rewards.size else 0.0
        return cls(min(lo, 0.0) / (1.0 - gamma), (max(hi, 0.0) + max(bonus, 0.0)) / (1.0 - gamma), lo, hi,
                   float(gamma))

    def summary(self) -> str:
        return (f"[{self.low:.4g}, {self.high:.4g}] (rewards in [{self.reward_low:.4g}, "
                f"{self.reward_high:.4g}], gamma {self.gamma:g})")


def buffer_rewards(replay_buffer) -> np.ndarray:
    """The rewards stored so far in an SB3 replay buffer (its filled rows)."""
    return replay_buffer.rewards[: replay_buffer.size()]
