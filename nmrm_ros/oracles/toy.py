"""Oracles of the three toy MIL datasets (paper App. C.1). Instances are 2-D; no actions.

- Toggle Switch: instance [ts, v]; r = v if ts = 1 else 0 (Markovian; no hidden state).
- Push Switch: instance [p, v]; pressing (p = 1) flips the hidden switch, h_{t+1} = h_t XOR p_t,
  h_0 = 0 (off); r_t = v if h_{t+1} = 1 else 0.
- Dial: instance [m, v]; d_{t+1} = d_t + m_t, d_0 = 0; r_t = d_{t+1} * v.

Choices where App. C is ambiguous (tested in tests/test_toy.py):
- Push Switch: the text says the hidden switch determines the reward "as before" (the toggle:
  v when on) but then writes "v if ts = 0"; a commented-out table has t = 1 - p. We keep "as
  before": reward v while the switch is on, the switch starting off, the press applied before the
  reward (the paper's h_{t+1} ordering). With ts = 0 rewarded instead, the task would be the
  same up to relabelling the switch.
- Dial: the text says r = d * v; the commented table says d + v. We follow the text.
"""

from __future__ import annotations

import numpy as np

from .base import Oracle


class ToggleSwitchOracle(Oracle):
    task = "toggle_switch"
    hidden_size = 0

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 0))

    def step(self, hidden, states, actions=None):
        s = self.check_states(states)
        return hidden, np.where(s[:, 0] == 1.0, s[:, 1], 0.0)


class PushSwitchOracle(Oracle):
    task = "push_switch"
    hidden_size = 1

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        s = self.check_states(states)
        h = np.where(s[:, :1] == 1.0, 1.0 - hidden, hidden)
        return h, np.where(h[:, 0] == 1.0, s[:, 1], 0.0)


class DialOracle(Oracle):
    task = "dial"
    hidden_size = 1

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        s = self.check_states(states)
        d = hidden + s[:, :1]
        return d, d[:, 0] * s[:, 1]
