"""The 2D navigation simulator shared by the Timer, Moving, Key and Charger tasks (paper App. D.1).

State `s_t = [x, y]` in `[0, 1]^2` (float32). Five discrete actions move the agent by 0.1:
0 = no-op, 1 = up (+y), 2 = down (-y), 3 = left (-x), 4 = right (+x). The motion vector is
corrupted by zero-mean Gaussian noise (std 0.02 per axis; also for no-op) and the result is clipped
into the square. Episodes last T = 100 steps and start in one of two spawn zones chosen with
probability 1/2. The environment gives no reward: rewards come from an oracle or a learnt model.

The dynamics are written once, vectorised over a batch of agents (`NavigationSimulator`); the
gymnasium env is that simulator with a batch of one. All arithmetic is float64 and each new
position is stored as float32, so what the env returns is exactly what a message carries.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

EPISODE_LENGTH = 100
STEP_SIZE = 0.1
MOTION_NOISE_STD = 0.02
N_ACTIONS = 5
ACTION_NAMES = ("noop", "up", "down", "left", "right")
#: Unit motion of each discrete action, (5, 2).
ACTION_VECTORS = np.array([[0, 0], [0, 1], [0, -1], [-1, 0], [1, 0]], dtype=np.float64)


@dataclass(frozen=True)
class Zone:
    """An axis-aligned rectangle, bounds inclusive."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def contains(self, states: np.ndarray) -> np.ndarray:
        """states: (..., 2) -> bool (...)."""
        x, y = states[..., 0], states[..., 1]
        return (x >= self.x_min) & (x <= self.x_max) & (y >= self.y_min) & (y <= self.y_max)


SPAWN_ZONES = (Zone(0.1, 0.2, 0.4, 0.6), Zone(0.8, 0.9, 0.4, 0.6))
TREASURE_ZONE = Zone(0.4, 0.6, 0.7, 0.9)
KEY_ZONE = Zone(0.4, 0.6, 0.1, 0.3)
#: Charger task: the agent charges wherever y <= 0.3.
CHARGE_Y_MAX = 0.3


class NavigationSimulator:
    """Vectorised dynamics of `n` independent agents. All randomness comes from `rng`.

    Random draws per call, in this order: `reset` draws the spawn zone choice (n) then x (n) then
    y (n); `step` draws the motion noise (n, 2).
    """

    def __init__(self, n: int, rng: np.random.Generator, continuous: bool = False) -> None:
        self.n = int(n)
        self.rng = rng
        self.continuous = continuous
        self.positions = np.zeros((self.n, 2), dtype=np.float32)

    def reset(self) -> np.ndarray:
        """Spawn every agent; returns positions (n, 2) float32."""
        right = self.rng.random(self.n) < 0.5
        x = self.rng.uniform(0.1, 0.2, self.n) + np.where(right, 0.7, 0.0)
        y = self.rng.uniform(0.4, 0.6, self.n)
        self.positions = np.stack([x, y], axis=1).astype(np.float32)
        return self.positions.copy()

    def motion(self, actions: np.ndarray) -> np.ndarray:
        """Noise-free motion (n, 2) float64 for discrete action indices (n,) or continuous
        actions (n, 2) in [-1, 1] (scaled by 0.1)."""
        if self.continuous:
            a = np.asarray(actions, dtype=np.float64).reshape(self.n, 2)
            return np.clip(a, -1.0, 1.0) * STEP_SIZE
        a = np.asarray(actions).reshape(self.n)
        if a.dtype.kind == "f":
            if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
                raise ValueError(f"discrete actions must be whole numbers in 0..4, got {a}")
            a = a.astype(np.int64)
        if np.any((a < 0) | (a >= N_ACTIONS)):
            raise ValueError(f"discrete actions must be in 0..4, got {a}")
        return ACTION_VECTORS[a] * STEP_SIZE

    def step(self, actions: np.ndarray) -> np.ndarray:
        """Move every agent; returns the new positions (n, 2) float32."""
        move = self.motion(actions)
        noise = self.rng.normal(0.0, MOTION_NOISE_STD, size=(self.n, 2))
        new = np.clip(self.positions.astype(np.float64) + move + noise, 0.0, 1.0)
        self.positions = new.astype(np.float32)
        return self.positions.copy()


def rollout_random(n: int, rng: np.random.Generator, length: int = EPISODE_LENGTH,
                   continuous: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Roll out `n` uniform-random-policy trajectories at once.

    Returns states (n, length + 1, 2) float32 (s_0..s_T; s_T is the final observation, on which
    no action is taken) and actions (n, length) int64 (or (n, length, 2) float32 if continuous).
    """
    sim = NavigationSimulator(n, rng, continuous=continuous)
    states = np.empty((n, length + 1, 2), dtype=np.float32)
    if continuous:
        actions = rng.uniform(-1.0, 1.0, size=(n, length, 2)).astype(np.float32)
    else:
        actions = rng.integers(0, N_ACTIONS, size=(n, length))
    states[:, 0] = sim.reset()
    for t in range(length):
        states[:, t + 1] = sim.step(actions[:, t])
    return states, actions


class NavigationEnv(gym.Env):
    """Rewardless gymnasium env of the 2D navigation tasks (reward is always 0.0).

    `task` only labels the env (the four tasks share the dynamics); `truncated` is set on step T.
    """

    metadata = {"render_modes": []}

    def __init__(self, task: str = "navigation", continuous: bool = False,
                 episode_length: int = EPISODE_LENGTH) -> None:
        self.task = task
        self.continuous = continuous
        self.episode_length = int(episode_length)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(2,), dtype=np.float32)
        if continuous:
            self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        else:
            self.action_space = gym.spaces.Discrete(N_ACTIONS)
        self._sim: NavigationSimulator | None = None
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._sim = NavigationSimulator(1, self.np_random, continuous=self.continuous)
        self._t = 0
        return self._sim.reset()[0], {"t": 0}

    def step(self, action):
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        if self._t >= self.episode_length:
            raise RuntimeError("episode is over (truncated); call reset()")
        obs = self._sim.step(np.asarray(action)[None])[0]
        self._t += 1
        return obs, 0.0, False, self._t >= self.episode_length, {"t": self._t}


# --- what the package knows of the four tasks (their TaskInfo) and their screening classes ---

#: returns a label may take: T = 100 steps of rewards in [0, 1] (Timer: -1 for each of the first 50, +1 after)
RETURN_RANGES = {"timer": (-50.0, 50.0), "moving": (0.0, 100.0), "key": (0.0, 100.0), "charger": (0.0, 100.0)}


#: what a person judges (the labelling page), from the paper's task descriptions (App. D.1)
_ROOM = ("The agent (the red dot; its path in red, from the start marked o) moves in a square room for "
         "100 steps, starting in one of the grey spawn zones. ")
INSTRUCTIONS = {
    "timer": _ROOM + "Each step it spends in the yellow treasure zone counts -1 during the first 50 steps "
                     "(steps 0-49) and +1 after them (steps 50-99; the last position, step 100, counts "
                     "nothing). The return: the steps in the treasure at 50-99 minus those at 0-49 "
                     "(from -50 to 50).",
    "moving": _ROOM + "The treasure is a box 0.2 wide that slides left and right along the yellow row at a "
                      "constant speed (0.02 a step, starting at x 0.4-0.6 and moving left, turning at the "
                      "walls); it is not drawn. Each step the agent is inside the moving treasure earns +1. "
                      "The return: the number of those steps (0 to 100).",
    "key": _ROOM + "The yellow treasure zone pays +1 for each step the agent spends in it, but only once the "
                   "agent has been in the blue key zone earlier in the episode; before that it pays 0. The "
                   "return: the steps in the treasure after the key was collected (0 to 100).",
    "charger": _ROOM + "Each step in the green charger strip (the bottom of the room) adds 0.02 to the agent's "
                       "charge, up to 1 (after 50 steps there). Each step in the yellow treasure zone earns the "
                       "charge it has then. The return: the sum of the charge over the steps spent in the "
                       "treasure (0 to 100).",
}
_SPAWN = ("spawn", "where the agent starts")
LEGEND = {"timer": (_SPAWN, ("treasure", "treasure: -1 a step at steps 0-49, +1 at 50-99")),
          "moving": (_SPAWN, ("treasure row", "the row the (unseen) treasure slides along")),
          "key": (_SPAWN, ("key", "key: visit it first"), ("treasure", "treasure: +1 a step once the key is collected")),
          "charger": (_SPAWN, ("charger", "charger: +0.02 charge a step, up to 1"),
                      ("treasure", "treasure: pays the charge, each step"))}


def navigation_task_info(task: str):
    """The TaskInfo of navigation task `task` (timer | moving | key | charger)."""
    from functools import partial

    from .info import TaskInfo

    return TaskInfo(task, 2, True, N_ACTIONS, EPISODE_LENGTH, family="navigation",
                    return_range=RETURN_RANGES[task], arena=(0.0, 1.0, 0.0, 1.0), screening="classes",
                    screening_classes=partial(screening_classes, task), classify=partial(classify, task),
                    navigation=True, zones=map_zones(task), instruction=INSTRUCTIONS[task], legend=LEGEND[task])


def map_zones(task: str) -> tuple:
    """The zones the views draw on a navigation task's arena: spawn (grey), treasure (gold;
    Moving: its row, dashed), key (blue), charger (green)."""
    from .info import MapZone

    def box(z: Zone, label, colour: str, style: str = "box") -> MapZone:
        return MapZone(label, colour, z.x_min, z.x_max, z.y_min, z.y_max, style)

    zones = [box(z, "spawn" if i == 0 else None, "grey") for i, z in enumerate(SPAWN_ZONES)]
    if task == "moving":
        zones.append(box(Zone(0.0, 1.0, TREASURE_ZONE.y_min, TREASURE_ZONE.y_max), "treasure row",
                         "goldenrod", "dashed"))
    else:
        zones.append(box(TREASURE_ZONE, "treasure", "goldenrod"))
    if task == "key":
        zones.append(box(KEY_ZONE, "key", "royalblue"))
    if task == "charger":
        zones.append(box(Zone(0.0, 1.0, 0.0, CHARGE_Y_MAX), "charger", "green"))
    return tuple(zones)


def screening_classes(task: str, key_fourth_class: bool = False):
    """The paper's classes and limits (App. D.2); the Key task's optional fourth class gets limits
    0.2 / 0.2 / 0.4 / 0.2 (no_key, key_no_treasure, treasure, treasure_no_key): the paper's 1:1:2
    ratio with a share for the new class."""
    from .info import ScreeningSpec

    if task == "timer":
        return ScreeningSpec(51 * 51, 0.002)
    if task == "moving":
        return ScreeningSpec(101, 0.05)
    if task == "key":
        if key_fourth_class:
            return ScreeningSpec(4, 0.2, {0: 0.2, 1: 0.2, 2: 0.4, 3: 0.2})
        return ScreeningSpec(3, 0.25, {0: 0.25, 1: 0.25, 2: 0.5})
    return ScreeningSpec(101 * 20, 0.002)  # charger


def classify(task: str, states: np.ndarray, labels, key_fourth_class: bool = False) -> np.ndarray:
    """Class ids (n,) of oracle-labelled trajectories (`labels`: OracleLabels); states (n, L, 2)
    are the labelled instances (the classes: `nmrm_ros.datasets.screening`'s docstring)."""
    live = np.arange(states.shape[1])[None, :] < labels.lengths[:, None]
    in_treasure = TREASURE_ZONE.contains(states) & live
    if task == "timer":
        neg = (in_treasure & (labels.rewards < 0)).sum(axis=1)
        pos = (in_treasure & (labels.rewards > 0)).sum(axis=1)
        return neg * 51 + pos
    if task == "moving":
        return (labels.rewards > 0).sum(axis=1)
    if task == "key":
        has_key = labels.hidden[:, :, 0] > 0
        got_key = (has_key & live).any(axis=1)
        treasure_with_key = (in_treasure & has_key).any(axis=1)
        cls = np.where(treasure_with_key, 2, np.where(got_key, 1, 0))
        if key_fourth_class:
            cls = np.where((cls == 0) & in_treasure.any(axis=1), 3, cls)
        return cls
    # charger
    num = in_treasure.sum(axis=1)
    charge_sum = (labels.hidden[:, :, 0] * in_treasure).sum(axis=1)
    mean = np.divide(charge_sum, num, out=np.zeros_like(charge_sum), where=num > 0)
    charge_bin = np.minimum(np.floor(mean / 0.05 + 1e-9).astype(np.int64) + 1, 20)
    return num * 20 + (charge_bin - 1)
