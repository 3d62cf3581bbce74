"""What a model and the oracle compute along given trajectories, step by step.

model_traces(model, states) -> rewards (N, T), hidden (N, T, 2k): the batched forward of a
`MILEnsemble` (or a `MILRewardModel`: an ensemble of one): the members' mean reward and the
serving member's served state [h'_{t+1}, tanh c'_{t+1}], as the reward_model node publishes them
(`nmrm_ros.mil.served_state`).
oracle_traces(task, states) -> rewards (N, T), hidden (N, T, k_oracle): the ground truth.
"""

from __future__ import annotations

import numpy as np
import torch

from ..mil.ensemble import as_ensemble
from ..mil.served_state import served_states
from ..oracles import make_oracle


#: trajectories per batched forward in `model_traces` (a pixel model's inputs are ~12 KB a step)
_CHUNK = 64


def model_traces(model, states: np.ndarray, lengths: np.ndarray | None = None, inputs=None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """states (N, T, d) (or (T, d) for one trajectory) -> rewards (N, T), served states
    (N, T, 2k): [h', tanh c'] per step. inputs: a function from states (n, T, d) to what the model
    reads (n, T, d') (a pixel task's images of positions: `pixel_inputs`); None: the states.
    Computed `_CHUNK` trajectories at a time."""
    states = np.asarray(states, np.float32)
    single = states.ndim == 2
    states = states[None] if single else states
    n, t = states.shape[:2]
    lens = np.full(n, t) if lengths is None else np.asarray(lengths)
    model = as_ensemble(model).eval()
    rewards, hidden = [], []
    for start in range(0, n, _CHUNK):
        part = states[start:start + _CHUNK]
        x = torch.as_tensor(np.asarray(part if inputs is None else inputs(part), np.float32))
        lens_part = torch.as_tensor(lens[start:start + _CHUNK])
        with torch.no_grad():
            rewards.append(model(x, lens_part).rewards.double().mean(0).numpy())
        hidden.append(served_states(model, x.numpy(), lens_part.numpy()))
    rewards, hidden = np.concatenate(rewards), np.concatenate(hidden)
    return (rewards[0], hidden[0]) if single else (rewards, hidden)


def pixel_inputs(task: str):
    """The `inputs` of `model_traces` for a pixel navigation task (`<t>_pixels`): positions
    (..., 2) of state task t -> the images its models read (`tasks.pixel_navigation`)."""
    from ..tasks.pixel_navigation import base_task, pixel_states

    base = base_task(task)
    return lambda positions: pixel_states(base, positions)


def oracle_traces(task: str, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """states (N, T, d) (or (T, d)) -> the oracle's r_t (N, T) and h_{t+1} (N, T, k)."""
    states = np.asarray(states, np.float64)
    single = states.ndim == 2
    states = states[None] if single else states
    oracle = make_oracle(task)
    n, t = states.shape[:2]
    hidden = oracle.initial_hidden(n)
    rewards = np.zeros((n, t))
    hiddens = np.zeros((n, t, hidden.shape[1]))
    for i in range(t):
        hidden, rewards[:, i] = oracle.step(hidden, states[:, i])
        hiddens[:, i] = hidden
    return (rewards[0], hiddens[0]) if single else (rewards, hiddens)
