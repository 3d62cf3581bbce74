"""Example of your own task as a module env with a memory task: a T-maze (a corridor with a cue).

Written after the agents' and models' settings were frozen (issue 50's held-out tasks), as a user
would write it: an env class and an oracle function in one file of their own.

    PYTHONPATH=examples nmrm dataset generate --task cue_corridor:CueCorridor,max_steps=30 \\
        --oracle examples/cue_corridor.py:oracle --n 2000 --out runs/cue.npz

The env: cells 0..LENGTH of a corridor and, at its far end, two arms (up, down). State (3,)
float32 = [x / LENGTH, arm (-1 down, 0 corridor, +1 up), cue]. The cue (+1 or -1, drawn at reset)
is shown at the first step only; afterwards it reads 0. Actions: 0 left, 1 right, 2 up, 3 down
(up/down move into an arm from the corridor's end, or back out of it; elsewhere they do nothing).
Episodes last STEPS steps. The env gives no reward of its own.

The oracle (non-Markovian: the state after step 0 does not say which arm pays): each step in the
arm the cue pointed to pays 1, each step in the other arm costs 1. Hidden state (T, 1): the cue.
Random-policy episodes (300, seeds 0-299): a third reach an arm; returns -16..12, two thirds 0. The
best policy earns 25 (the cued arm from step 5); one without memory of the cue earns 0 on average.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

LENGTH = 4
STEPS = 30


class CueCorridor(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, length: int = LENGTH, steps: int = STEPS) -> None:
        self.length, self.steps = int(length), int(steps)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(4)
        self.x = self.arm = self.t = 0
        self.cue = 1

    def _obs(self) -> np.ndarray:
        return np.array([self.x / self.length, self.arm, self.cue if self.t == 0 else 0.0], np.float32)

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        self.x, self.arm, self.t = 0, 0, 0
        self.cue = int(self.np_random.choice([-1, 1]))
        return self._obs(), {}

    def step(self, action):
        a = int(action)
        if self.arm == 0:
            if a == 0:
                self.x = max(0, self.x - 1)
            elif a == 1:
                self.x = min(self.length, self.x + 1)
            elif self.x == self.length and a in (2, 3):
                self.arm = 1 if a == 2 else -1
        elif (a == 3 and self.arm == 1) or (a == 2 and self.arm == -1):
            self.arm = 0  # back out of the arm
        self.t += 1
        return self._obs(), 0.0, False, self.t >= self.steps, {}


def oracle(states: np.ndarray, actions: np.ndarray | None):
    """rewards (T,): +1 a step in the cued arm, -1 in the other, 0 in the corridor; hidden (T, 1):
    the cue (read from the first state)."""
    cue = float(np.sign(states[0, 2])) or 1.0
    arm = np.rint(states[:, 1])
    rewards = np.where(arm == cue, 1.0, np.where(arm == -cue, -1.0, 0.0))
    return rewards, np.full((len(states), 1), cue)
