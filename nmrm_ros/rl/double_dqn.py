"""Double DQN (van Hasselt et al., 2016) on stable-baselines3's DQN, as App. E of the paper uses.

SB3's `DQN` bootstraps from `max_a Q_target(s', a)`, which is plain DQN. The double target picks
the action with the online network and evaluates it with the target network:

    y = r + gamma * (1 - done) * Q_target(s', argmax_a Q_online(s', a))

`DoubleDQN` differs from `DQN` in that target (`double_q_target`) and in bounding it
(`bound_values`, on by default): every target is clipped to the highest value that the rewards in
the replay buffer allow, `nmrm_ros.rl.value_bound`. Bootstrapping through max_a cannot then run
away past what any policy can earn (the collapse of issue 50: max Q three times its bound); a
target below the bound is left as it is, so a healthy run is unchanged bit for bit. (The lower end
is not enforced: maximising bootstraps overestimate, and a young network's slightly negative
values on rewards >= 0 would otherwise be clipped in every run.) Everything else (replay, epsilon
schedule, Polyak updates, Huber loss, gradient clipping, saving/loading) is SB3's.
"""

from __future__ import annotations

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import DQN

from .overlapped_training import OverlappedTraining
from .value_bound import ValueBound, buffer_rewards


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
    comparisons); `bound_values=False` leaves targets unclipped. `value_bound` is the bound of the
    last gradient step (None before the first). `overlap_training`: see `overlapped_training`.
    """

    def __init__(self, *args, double_q: bool = True, bound_values: bool = True, **kwargs) -> None:
        self.double_q = double_q
        self.bound_values = bound_values
        self.value_bound: ValueBound | None = None
        self.targets_clipped = 0  # targets clipped to the bound so far
        super().__init__(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self._defer_train(gradient_steps, batch_size):
            return
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        bound = None
        if self.bound_values:  # from every reward stored so far (a relabelled buffer included)
            bound = self.value_bound = ValueBound.of(buffer_rewards(self.replay_buffer), self.gamma)
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
                if bound is not None:
                    clipped = target.clamp(max=bound.high)
                    self.targets_clipped += int((clipped != target).sum())
                    target = clipped
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
        if bound is not None:
            self.logger.record("train/value_bound", bound.high)
            self.logger.record("train/targets_clipped", self.targets_clipped)

    def _excluded_save_params(self) -> list:
        return super()._excluded_save_params() + ["value_bound"]
