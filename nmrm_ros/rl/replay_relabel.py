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

Relabelling alone is not enough: the agent's networks were fitted to the old model's served state,
and the new model's hidden units mean something else (another training run), so the greedy policy
is arbitrary on the new inputs until the networks are refitted — the agent that earned 170 per
episode on model k earned 0 from the first episode on model k + 1 (issue 50, the patrol loop).
`catch_up` refits them on the relabelled buffer before the agent acts again; `adopt_model` does
both, and is what the loop and the agent node call when their model changes.
"""

from __future__ import annotations

import numpy as np

from .config import TRUST_DEFAULTS
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


def catch_up(agent, steps: int) -> int:
    """`steps` gradient steps of an SB3 off-policy `agent` (our DoubleDQN or SplitLRSAC) on its
    replay buffer, with its target networks following as they do in training (DQN: a Polyak
    update per `target_update_interval` environment steps' worth of gradient steps; SAC's `train`
    updates its own), but never more steps than the buffer holds transitions (training at one
    gradient step per transition took no more to gather them). No environment step is taken and
    the exploration schedule does not move. Returns the gradient steps taken (0 before the agent
    has `learning_starts` transitions)."""
    from stable_baselines3.common.utils import polyak_update

    steps = int(steps)
    buffer = agent.replay_buffer
    stored = (buffer.buffer_size if buffer.full else buffer.pos) * buffer.n_envs
    if steps <= 0 or stored < max(int(agent.learning_starts), int(agent.batch_size)):
        return 0
    steps = min(steps, stored)
    overlap, agent.overlap_training = getattr(agent, "overlap_training", False), False
    try:
        if hasattr(agent, "q_net_target"):  # DQN: its target moves in _on_step, not in train()
            freq = max(int(agent.train_freq.frequency), 1)
            per_update = max(1, round(max(agent.target_update_interval // agent.n_envs, 1)
                                      * max(int(agent.gradient_steps), 1) / freq))
            done = 0
            while done < steps:
                n = min(per_update, steps - done)
                agent.train(gradient_steps=n, batch_size=agent.batch_size)
                polyak_update(agent.q_net.parameters(), agent.q_net_target.parameters(), agent.tau)
                polyak_update(agent.batch_norm_stats, agent.batch_norm_stats_target, 1.0)
                done += n
        else:
            agent.train(gradient_steps=steps, batch_size=agent.batch_size)
    finally:
        agent.overlap_training = overlap
    return steps


def adopt_model(agent, stepper: HiddenStateStepper, state_size: int, catch_up_steps: int = TRUST_DEFAULTS["catch_up_steps"]) -> tuple:
    """The agent's reward model has changed to `stepper`: relabel its replay buffer
    (`relabel_replay_buffer`), then refit its networks on it (`catch_up`).
    Returns (transitions relabelled, gradient steps taken)."""
    relabelled = relabel_replay_buffer(agent.replay_buffer, stepper, state_size)
    return relabelled, catch_up(agent, catch_up_steps)
