"""Example oracle for your own task: MountainCar, paid for a swing, i.e. for being up the right
slope only once the car has been up the left one (a non-Markovian reward: the state does not say
where the car has been).

    nmrm dataset generate --task gym:MountainCar-v0 --oracle examples/mountaincar_swing.py:oracle ...

states (T, 2) = [position, velocity] per step; actions (T, 1) or None (not used). A step pays 1
while the position is right of -0.45 after an earlier (or this) step left of -0.65. Thresholds
from 300 random-policy episodes of 200 steps (seeds 0-299): about half go left of -0.65 (median
lowest position -0.65) and three quarters right of -0.45 (median highest -0.40), so random
episodes earn 0 to ~60. Returns rewards (T,) and the hidden state (T, 1): [been left] after step t.
"""

import numpy as np

LEFT, RIGHT = -0.65, -0.45


def oracle(states: np.ndarray, actions: np.ndarray | None):
    x = states[:, 0]
    been_left = np.maximum.accumulate(x < LEFT)
    rewards = (been_left & (x > RIGHT)).astype(np.float64)
    return rewards, been_left[:, None].astype(np.float64)
