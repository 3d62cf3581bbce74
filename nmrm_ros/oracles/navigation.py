"""Oracles of the 2D navigation tasks (paper App. D.1): Timer, Moving, Key, Charger.

Hidden-state updates that accumulate decimal steps (Moving's treasure position, Charger's charge)
are rounded to 10 decimals after each update, so that 0.4 - 20 * 0.02 is exactly 0 and 50
charges of 0.02 are exactly 1, as the paper's definitions intend.
"""

from __future__ import annotations

import numpy as np

from ..tasks.navigation import CHARGE_Y_MAX, KEY_ZONE, TREASURE_ZONE
from .base import Oracle

_DECIMALS = 10


class TimerOracle(Oracle):
    """h = time index; the treasure gives -1 per step while h_{t+1} <= 50, +1 after."""

    task = "timer"
    hidden_size = 1
    switch_time = 50

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        states = self.check_states(states)
        h = hidden + 1.0
        sign = np.where(h[:, 0] <= self.switch_time, -1.0, 1.0)
        return h, TREASURE_ZONE.contains(states) * sign


class MovingOracle(Oracle):
    """h = [left edge, velocity] of a 0.2-wide treasure (y in [0.7, 0.9]) oscillating in x."""

    task = "moving"
    hidden_size = 2
    width = 0.2

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.tile([0.4, -0.02], (n, 1))

    def step(self, hidden, states, actions=None):
        states = self.check_states(states)
        pos = np.round(hidden[:, 0] + hidden[:, 1], _DECIMALS)
        vel = np.where((pos > 0.0) & (pos < 0.8), hidden[:, 1], -hidden[:, 1])
        x, y = states[:, 0], states[:, 1]
        r = (x >= pos) & (x <= pos + self.width) & (y >= TREASURE_ZONE.y_min) & (y <= TREASURE_ZONE.y_max)
        return np.stack([pos, vel], axis=1), r.astype(np.float64)


class KeyOracle(Oracle):
    """h = 1 once the key zone was visited; the treasure gives h_{t+1} per step."""

    task = "key"
    hidden_size = 1

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        states = self.check_states(states)
        h = np.where(KEY_ZONE.contains(states)[:, None], 1.0, hidden)
        return h, TREASURE_ZONE.contains(states) * h[:, 0]


class ChargerOracle(Oracle):
    """h = charge, +0.02 per step where y <= 0.3, capped at 1; the treasure gives h_{t+1}."""

    task = "charger"
    hidden_size = 1
    rate = 0.02

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        states = self.check_states(states)
        charging = (states[:, 1] <= CHARGE_Y_MAX)[:, None]
        h = np.where(charging, np.minimum(np.round(hidden + self.rate, _DECIMALS), 1.0), hidden)
        return h, TREASURE_ZONE.contains(states) * h[:, 0]
