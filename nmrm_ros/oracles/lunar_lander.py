"""Oracle of the modified Lunar Lander task (paper App. D.1).

h = steps spent on the pad (capped at 50). While h_{t+1} < 50 the reward is
R_pad + R_shaping(s, y_target=0); from then on R_no_contact + R_hover + R_shaping(s, y_target=1).
`components` returns the four terms separately (each already gated by the phase), so that
they sum to the reward.
"""

from __future__ import annotations

import numpy as np

from .base import Oracle

PAD_TARGET = 50
COMPONENTS = ("pad", "no_contact", "hover", "shaping")
PAD_HALF_WIDTH = 0.2  # the pad: |x| <= 0.2 on the ground
HOVER_ZONE = (-0.5, 0.5, 0.75, 1.25)  # x_min, x_max, y_min, y_max


def r_pad(s: np.ndarray) -> np.ndarray:
    """1 if -0.2 <= x <= 0.2 and both legs touch the ground. s: (n, 8) -> (n,)."""
    return ((s[:, 0] >= -PAD_HALF_WIDTH) & (s[:, 0] <= PAD_HALF_WIDTH) & (s[:, 6] == 1)
            & (s[:, 7] == 1)).astype(np.float64)


def r_no_contact(s: np.ndarray) -> np.ndarray:
    """1 if neither leg touches the ground."""
    return ((s[:, 6] == 0) & (s[:, 7] == 0)).astype(np.float64)


def r_hover(s: np.ndarray) -> np.ndarray:
    """1 if -0.5 <= x <= 0.5 and 0.75 <= y <= 1.25."""
    x0, x1, y0, y1 = HOVER_ZONE
    return ((s[:, 0] >= x0) & (s[:, 0] <= x1) & (s[:, 1] >= y0) & (s[:, 1] <= y1)).astype(np.float64)


def r_shaping(s: np.ndarray, y_target: float) -> np.ndarray:
    """0.1 * max(2 - (|(x, y - y_target)| + |(vx, vy)| + |angle| + |angular velocity|), 0)."""
    dist = np.hypot(s[:, 0], s[:, 1] - y_target)
    speed = np.hypot(s[:, 2], s[:, 3])
    return 0.1 * np.maximum(2.0 - (dist + speed + np.abs(s[:, 4]) + np.abs(s[:, 5])), 0.0)


class LunarLanderOracle(Oracle):
    task = "lunar_lander"
    hidden_size = 1
    state_size = 8

    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, 1))

    def components(self, hidden_next: np.ndarray, states: np.ndarray) -> dict[str, np.ndarray]:
        """The four reward terms (n,) each, gated by phase (h_{t+1} < 50 or not); they sum to r_t."""
        s = self.check_states(states)
        landing = hidden_next[:, 0] < PAD_TARGET
        return {
            "pad": np.where(landing, r_pad(s), 0.0),
            "no_contact": np.where(landing, 0.0, r_no_contact(s)),
            "hover": np.where(landing, 0.0, r_hover(s)),
            "shaping": np.where(landing, r_shaping(s, 0.0), r_shaping(s, 1.0)),
        }

    def step(self, hidden, states, actions=None):
        s = self.check_states(states)
        h = np.where(r_pad(s)[:, None] == 1.0, np.minimum(hidden + 1.0, PAD_TARGET), hidden)
        parts = self.components(h, s)
        return h, parts["pad"] + parts["no_contact"] + parts["hover"] + parts["shaping"]

    def label_components(self, states: np.ndarray, lengths: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Per-step reward components of a batch of trajectories: name -> (n, L)."""
        labels = self.label(states, lengths=lengths)
        n, horizon = labels.rewards.shape
        out = {k: np.zeros((n, horizon)) for k in COMPONENTS}
        for t in range(horizon):
            live = t < labels.lengths
            parts = self.components(labels.hidden[:, t], np.asarray(states)[:, t])
            for k in COMPONENTS:
                out[k][live, t] = parts[k][live]
        return out
