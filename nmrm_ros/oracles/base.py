"""The oracle interface: a task's ground-truth hidden state and non-Markovian reward.

Order of computation (paper Sec. 3.1, App. D footnote): at time t the hidden state is updated
first, `h_{t+1} = delta(h_t, s_t, a_t)`, then the reward is `r_t = R(s_t, a_t, h_{t+1})`, then the
environment moves to `s_{t+1}`. The return of a trajectory of length L is `sum_{t<L} r_t`.

Oracles are vectorised over a batch of n trajectories: hidden (n, k) float64, states (n, d),
actions (n, ...) or None.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np


@dataclass
class OracleLabels:
    """Ground truth of a batch of trajectories (padded to the longest; padding is zero).

    returns (n,) float64; rewards (n, L) float64; hidden (n, L, k) float64 where hidden[:, t] is
    h_{t+1}; lengths (n,) int64.
    """

    returns: np.ndarray
    rewards: np.ndarray
    hidden: np.ndarray
    lengths: np.ndarray


class Oracle(ABC):
    """A task's labeller: `delta`, `R` and `h_0` (see module docstring)."""

    #: task name, e.g. "key"
    task: str = ""
    #: size k of the hidden state vector
    hidden_size: int = 1
    #: size d of the state vector the oracle expects
    state_size: int = 2

    @abstractmethod
    def initial_hidden(self, n: int = 1) -> np.ndarray:
        """h_0 for n trajectories, (n, k) float64."""

    @abstractmethod
    def step(self, hidden: np.ndarray, states: np.ndarray,
             actions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One step for n trajectories: returns (h_{t+1} (n, k), r_t (n,))."""

    def check_states(self, states: np.ndarray) -> np.ndarray:
        """Validate a batch of states (n, d); raises ValueError on a wrong size or NaN."""
        states = np.asarray(states, dtype=np.float64)
        if states.ndim != 2 or states.shape[1] != self.state_size:
            raise ValueError(f"{self.task} oracle: expected states of shape (n, {self.state_size}), "
                             f"got {states.shape}")
        if not np.all(np.isfinite(states)):
            raise ValueError(f"{self.task} oracle: states contain NaN or inf")
        return states

    def label(self, states: np.ndarray, actions: np.ndarray | None = None,
              lengths: np.ndarray | None = None) -> OracleLabels:
        """Label a batch of trajectories.

        states (n, L, d) (a final extra observation s_L may be included: pass `lengths`);
        actions (n, L, ...) or None; lengths (n,) numbers of (s, a) pairs to label, default L.
        Steps beyond a trajectory's length are not labelled (reward 0, hidden 0).
        """
        states = np.asarray(states)
        if states.ndim != 3:
            raise ValueError(f"states must be (n, L, d), got shape {states.shape}")
        n = states.shape[0]
        if lengths is None:
            lengths = np.full(n, states.shape[1] if actions is None else np.asarray(actions).shape[1])
        lengths = np.asarray(lengths, dtype=np.int64)
        horizon = int(lengths.max()) if n else 0
        if horizon > states.shape[1]:
            raise ValueError(f"lengths up to {horizon} but only {states.shape[1]} states")
        rewards = np.zeros((n, horizon))
        hidden = np.zeros((n, horizon, self.hidden_size))
        h = self.initial_hidden(n)
        for t in range(horizon):
            a_t = None if actions is None else np.asarray(actions)[:, t]
            h_next, r = self.step(h, states[:, t], a_t)
            live = t < lengths
            h = np.where(live[:, None], h_next, h)
            rewards[live, t] = r[live]
            hidden[live, t] = h_next[live]
        return OracleLabels(rewards.sum(axis=1), rewards, hidden, lengths)

    def tracker(self) -> "OracleTracker":
        """A stateful single-trajectory stepper (for online use)."""
        return OracleTracker(self)


class OracleTracker:
    """Carries one trajectory's hidden state: `reset()`, then `step(s_t, a_t) -> (r_t, h_{t+1})`
    (the same order as `nmrm_ros.mil.OnlineRewardModel.step`)."""

    def __init__(self, oracle: Oracle) -> None:
        self.oracle = oracle
        self.reset()

    def reset(self) -> None:
        self.hidden = self.oracle.initial_hidden(1)
        self.t = 0
        self.total = 0.0

    def step(self, state: np.ndarray, action: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        s = np.asarray(state, dtype=np.float64).reshape(1, -1)
        a = None if action is None else np.asarray(action).reshape(1, -1)
        self.hidden, r = self.oracle.step(self.hidden, s, a)
        self.t += 1
        self.total += float(r[0])
        return float(r[0]), self.hidden[0].copy()
