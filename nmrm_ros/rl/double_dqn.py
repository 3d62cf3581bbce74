"""Double DQN (van Hasselt et al., 2016) on stable-baselines3's DQN, as App. E of the paper uses.

SB3's `DQN` bootstraps from `max_a Q_target(s', a)`, which is plain DQN. The double target picks
the action with the online network and evaluates it with the target network:

    y = r + gamma * (1 - done) * Q_target(s', argmax_a Q_online(s', a))

`DoubleDQN` differs from `DQN` in that target only (`double_q_target`); everything else (replay,
epsilon schedule, Polyak updates, Huber loss, gradient clipping, saving/loading) is SB3's.
"""

from __future__ import annotations

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import DQN

from .overlapped_training import OverlappedTraining


def double_q_target(q_online_next: th.Tensor, q_target_next: th.Tensor, rewards: th.Tensor,
                    dones: th.Tensor, discounts: th.Tensor | float) -> th.Tensor:
    """The double Q-learning TD target.

    q_online_next, q_target_next: (batch, n_actions) Q-values of s' from the online and the target
    network; rewards, dones: (batch, 1); discounts: gamma (or (batch, 1) for n-step returns).
    Returns (batch, 1).
    """
    best = q_online_next.argmax(dim=1, keepdim=True)
    return rewards + (1.0 - dones) * discounts * th.gather(q_target_next, 1, best)


class DoubleDQN(OverlappedTraining, DQN):
    """stable-baselines3 DQN with the double Q-learning target (see the module docstring).

    Takes DQN's parameters unchanged. `double_q=False` gives SB3's plain DQN target back (for
    comparisons). `overlap_training`: see `overlapped_training`.
    """

    def __init__(self, *args, double_q: bool = True, **kwargs) -> None:
        self.double_q = double_q
        super().__init__(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self._defer_train(gradient_steps, batch_size):
            return
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = data.discounts if data.discounts is not None else self.gamma
            with th.no_grad():
                q_target_next = self.q_net_target(data.next_observations)
                if self.double_q:
                    target = double_q_target(self.q_net(data.next_observations), q_target_next,
                                             data.rewards, data.dones, discounts)
                else:
                    target = (data.rewards + (1 - data.dones) * discounts
                              * q_target_next.max(dim=1, keepdim=True).values)
            q = th.gather(self.q_net(data.observations), 1, data.actions.long())
            loss = F.smooth_l1_loss(q, target)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))
