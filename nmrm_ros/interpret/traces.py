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


def model_traces(model, states: np.ndarray, lengths: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """states (N, T, d) (or (T, d) for one trajectory) -> rewards (N, T), served states
    (N, T, 2k): [h', tanh c'] per step."""
    states = np.asarray(states, np.float32)
    single = states.ndim == 2
    x = torch.as_tensor(states[None] if single else states)
    n, t = x.shape[:2]
    lens = torch.full((n,), t) if lengths is None else torch.as_tensor(np.asarray(lengths))
    model = as_ensemble(model).eval()
    with torch.no_grad():
        rewards = model(x, lens).rewards.double().mean(0).numpy()
    hidden = served_states(model, x.numpy(), lens.numpy())
    return (rewards[0], hidden[0]) if single else (rewards, hidden)


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
