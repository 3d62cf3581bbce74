"""Relabel an off-policy agent's replay buffer when the reward model it learns from changes.

The agent observes [s_t, h'_{t+1}] and is paid r'_t by a reward model; when the model is retrained,
both change meaning: the stored transitions carry the old model's hidden states and rewards. Since
h' and r' are functions of the states seen so far in an episode, the stored raw states s_t are
enough to recompute them: every stored episode is stepped through the new model from its first
stored state, exactly as the `RewardModelWrapper` would have served it (PEBBLE, Lee et al. 2021,
relabels rewards this way; here the hidden part of the observation is relabelled too).

An episode whose first transitions were overwritten (a full buffer that wrapped round) is stepped
from its oldest stored transition, so its hidden states start from h'_0 too early: an
approximation, for at most one episode per environment.
"""

from __future__ import annotations

import numpy as np

from .wrappers import HiddenStateStepper


def relabel_replay_buffer(buffer, stepper: HiddenStateStepper, state_size: int) -> int:
    """Recompute the reward and the served state of every transition in an SB3 `ReplayBuffer`
    with `stepper` (e.g. an `OnlineRewardModel` of the new model), episode by episode in the order
    they were stored (episodes end where `dones` is set). Observations are [s (state_size), served]
    (the served part must keep its size) or s only (then the rewards alone are relabelled).
    Returns the number of transitions relabelled."""
    if getattr(buffer, "optimize_memory_usage", False) or buffer.next_observations is None:
        raise ValueError("relabelling needs a replay buffer with next_observations "
                         "(optimize_memory_usage=False)")
    size = buffer.buffer_size if buffer.full else buffer.pos
    order = (np.arange(size) + buffer.pos) % size if buffer.full else np.arange(size)
    d = int(state_size)
    obs, nxt = buffer.observations, buffer.next_observations
    hidden = obs.shape[-1] > d
    for env in range(buffer.n_envs):
        current = None  # (r'_t, served_{t+1}) of the transition's first state, once stepped
        for idx in order:
            if current is None:  # the first stored transition of an episode
                stepper.reset()
                current = stepper.step(obs[idx, env, :d].astype(np.float64))
            reward, served = current
            buffer.rewards[idx, env] = reward
            following = stepper.step(nxt[idx, env, :d].astype(np.float64))
            if hidden:
                obs[idx, env, d:] = served
                nxt[idx, env, d:] = following[1]
            current = None if buffer.dones[idx, env] else following
    return int(size * buffer.n_envs)
