"""A fake robot for tests and the docs: a unicycle in a 2 m x 2 m box, and a delivery task on it
with a non-Markovian oracle (reaching the goal pays only after the pickup has been visited).

The same dynamics run in two places: `DeliveryEnv` (a Gymnasium env, so `nmrm dataset generate
--task nmrm_ros.robots.delivery:DeliveryEnv` makes offline data and the task spec gives the graph
its state size and actions: TASK) and the `fake_robot` node (real time: it publishes nav_msgs/Odometry
and a sensor_msgs/LaserScan of the box and obeys geometry_msgs/Twist, as a robot does), which the
bridges connect to the graph with config/robots/fake_delivery.yaml.

State [x, y, heading] (m, m, rad). One step is DT = 0.1 s at the commanded (v, w). Actions
(ACTIONS): 0 forward, 1 turn left, 2 turn right (slowly moving on), 3 stop. The oracle: hidden [picked up,
delivered-so-far]; reward 1 per step in the goal after the pickup was visited (like Key's treasure).
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

SIZE = 2.0                       # the box is [0, SIZE] x [0, SIZE] (m)
DT = 0.1                         # s per step
ACTIONS = {0: (0.5, 0.0), 1: (0.2, 4.0), 2: (0.2, -4.0), 3: (0.0, 0.0)}  # index -> (v m/s, w rad/s)
PICKUP = (0.5, 1.5, 0.4)         # centre x, y and radius (m)
GOAL = (1.5, 1.5, 0.4)
# with these, 9.4% of uniformly random 200-step episodes deliver (1500 episodes, seed 0), and 41%
# visit the pickup: a random-policy dataset has every kind of episode
START = (1.0, 1.0)               # episodes start here, heading drawn at random
#: what the labelling page and the visualizer draw: the box, and the zones as squares round their circles
ARENA = {"bounds": [0.0, SIZE, 0.0, SIZE],
         "zones": [[c[0] - c[2], c[0] + c[2], c[1] - c[2], c[1] + c[2], kind] for c, kind in
                   (((1.0, 1.0, 0.1), "spawn"), (PICKUP, "pickup"), (GOAL, "goal"))],
         "legend": {"spawn": "where the robot starts", "pickup": "pickup: visit it first",
                    "goal": "goal: +1 a step once the pickup was visited"}}
#: what a person labelling an episode judges (the labelling page shows it)
INSTRUCTION = ("The robot (its path in red, from the start marked o) drives in a 2 m x 2 m box for 200 steps. "
               "It must first visit the blue pickup zone, then go to the yellow goal zone: each step in the goal "
               "after the pickup was visited earns +1; the goal pays nothing before that. The return: the steps "
               "in the goal after the pickup (0 to 200).")
MAX_STEPS = 200                  # steps per episode (the task spec's max_steps, the robot spec's max_steps)
TASK = f"nmrm_ros.robots.delivery:DeliveryEnv,max_steps={MAX_STEPS},xy=0/1"  # the task spec


def step_unicycle(x: float, y: float, heading: float, v: float, w: float, dt: float = DT) -> tuple:
    """The pose after dt at (v, w), kept inside the box (a wall stops the motion across it)."""
    heading = math.atan2(math.sin(heading + w * dt), math.cos(heading + w * dt))
    x = min(max(x + v * math.cos(heading) * dt, 0.0), SIZE)
    y = min(max(y + v * math.sin(heading) * dt, 0.0), SIZE)
    return x, y, heading


def scan(x: float, y: float, heading: float, beams: int = 36, range_max: float = 3.0) -> list:
    """Distances (m) from the pose to the box's walls along `beams` rays evenly round from the
    heading (a LaserScan of the box world); beyond range_max: inf."""
    out = []
    for i in range(beams):
        a = heading + 2 * math.pi * i / beams
        dx, dy = math.cos(a), math.sin(a)
        hits = []
        if dx > 1e-9:
            hits.append((SIZE - x) / dx)
        if dx < -1e-9:
            hits.append(-x / dx)
        if dy > 1e-9:
            hits.append((SIZE - y) / dy)
        if dy < -1e-9:
            hits.append(-y / dy)
        d = min(hits)
        out.append(d if d <= range_max else math.inf)
    return out


def _inside(x, y, zone) -> np.ndarray:
    cx, cy, r = zone
    return (np.asarray(x) - cx) ** 2 + (np.asarray(y) - cy) ** 2 <= r * r


def oracle(states: np.ndarray, actions=None):
    """Rewards (T,) and hidden (T, 2) of one trajectory's states (T, 3): 1 per step in the goal
    once the pickup has been visited; hidden = [picked up, in the goal after the pickup]."""
    states = np.asarray(states, dtype=np.float64)
    picked = np.maximum.accumulate(_inside(states[:, 0], states[:, 1], PICKUP))
    paid = picked & _inside(states[:, 0], states[:, 1], GOAL)
    return paid.astype(np.float64), np.stack([picked, paid], axis=1).astype(np.float64)


class DeliveryEnv(gym.Env):
    """The delivery task as a Gymnasium env (no reward of its own: the oracle judges)."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(np.array([0.0, 0.0, -math.pi], np.float32),
                                                np.array([SIZE, SIZE, math.pi], np.float32))
        self.action_space = gym.spaces.Discrete(len(ACTIONS))
        self.pose = (*START, 0.0)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pose = (*START, float(self.np_random.uniform(-math.pi, math.pi)))
        self.t = 0
        return np.array(self.pose, np.float32), {}

    def step(self, action):
        v, w = ACTIONS[int(action)]
        self.pose = step_unicycle(*self.pose, v, w)
        self.t += 1
        return np.array(self.pose, np.float32), 0.0, False, False, {}  # the task spec's max_steps ends it
