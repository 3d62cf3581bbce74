"""Example of your own task on the fake robot with another task and another action table: a patrol.

Written after the agents' and models' settings were frozen (issue 50's held-out tasks). The robot
is the fake robot's unicycle in its 2 m x 2 m box (`nmrm_ros.robots.delivery.step_unicycle`, 0.1 s
a step), driven by its own action table (ACTIONS: two speeds ahead, turns on the spot, arcs; for
the bridges: examples/patrol_robot.yaml). The task: visit both stations, west and east (in any
order), then come home to the middle; each step at home once both stations were visited pays 1.

    nmrm dataset generate --task "patrol_robot:PatrolEnv,max_steps=200,xy=0/1" \\
        --oracle examples/patrol_robot.py:oracle --n 2000 --out runs/patrol.npz   # PYTHONPATH=examples

State [x, y, heading] (m, m, rad), as the fake robot's odometry. The oracle's hidden state: [west
visited, east visited]. Random-policy episodes: see WEST, EAST, HOME below.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from nmrm_ros.robots.delivery import DeliveryEnv, step_unicycle

#: index -> (v m/s, w rad/s): ahead fast, ahead slow, turn left / right on the spot, arc left / right
ACTIONS = {0: (0.6, 0.0), 1: (0.25, 0.0), 2: (0.0, 3.0), 3: (0.0, -3.0), 4: (0.3, 2.0), 5: (0.3, -2.0)}
WEST = (0.5, 1.0, 0.35)          # centre x, y and radius (m); home overlaps the stations' inner edges
EAST = (1.5, 1.0, 0.35)
HOME = (1.0, 1.0, 0.45)
#: random-policy episodes of 200 steps (500, seeds 0-499): 6% visit both stations, 4.2% are paid
#: (mean return 0.64, the best 42); with smaller zones (stations 0.65 m out, home 0.3 m) 0.4% were
#: paid, too few for a dataset


def _inside(x, y, zone) -> np.ndarray:
    cx, cy, r = zone
    return (np.asarray(x) - cx) ** 2 + (np.asarray(y) - cy) ** 2 <= r * r


def oracle(states: np.ndarray, actions=None):
    """Rewards (T,): 1 a step at home once both stations were visited; hidden (T, 2): [west
    visited, east visited] after step t."""
    states = np.asarray(states, dtype=np.float64)
    x, y = states[:, 0], states[:, 1]
    west = np.maximum.accumulate(_inside(x, y, WEST))
    east = np.maximum.accumulate(_inside(x, y, EAST))
    rewards = (west & east & _inside(x, y, HOME)).astype(np.float64)
    return rewards, np.stack([west, east], axis=1).astype(np.float64)


class PatrolEnv(DeliveryEnv):
    """The fake robot's env (`DeliveryEnv`: the box, the start at home, a random heading) driven by
    the patrol's action table; no reward of its own: the oracle judges."""

    def __init__(self) -> None:
        super().__init__()
        self.action_space = gym.spaces.Discrete(len(ACTIONS))

    def step(self, action):
        v, w = ACTIONS[int(action)]
        self.pose = step_unicycle(*self.pose, v, w)
        self.t += 1
        return np.array(self.pose, np.float32), 0.0, False, False, {}  # the task spec's max_steps ends it
