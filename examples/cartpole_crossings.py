"""Example oracle for your own task: CartPole, paid only once the cart has crossed the centre line
in both directions (a non-Markovian reward: the state does not say what the cart did before).

    nmrm dataset generate --task gym:CartPole-v1 --oracle examples/cartpole_crossings.py:oracle ...

states (T, 4) = [cart x, cart velocity, pole angle, pole angular velocity] per step; actions (T, 1)
or None (not used). Returns rewards (T,) and the hidden state (T, 2): [crossed rightwards, crossed
leftwards] after step t.
"""

import numpy as np


def oracle(states: np.ndarray, actions: np.ndarray | None):
    x = states[:, 0]
    previous = np.concatenate([[x[0]], x[:-1]])
    rightwards = np.maximum.accumulate((previous < 0) & (x >= 0))
    leftwards = np.maximum.accumulate((previous >= 0) & (x < 0))
    hidden = np.stack([rightwards, leftwards], axis=1).astype(np.float64)
    rewards = (rightwards & leftwards).astype(np.float64)
    return rewards, hidden
