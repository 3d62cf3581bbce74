"""A task nobody here wrote the environment of, seen through a camera: MiniGrid's empty room
(Farama's `minigrid` package), observed as its top-down RGB image, with a non-Markovian oracle.

    PYTHONPATH=examples nmrm dataset screen --task "minigrid_corners:make_env,max_steps=60,privileged=pose" \
        --oracle minigrid_corners:oracle --n 1000 --out runs/minigrid/data.npz

The agent (the red triangle) starts anywhere in a 4 x 4 room, facing anywhere, and turns left,
turns right or moves forward (MiniGrid's first three actions); reaching the green goal square
ends the episode. The model sees only the image (`tile_size` pixels a cell: 48 x 48 x 3 by
default); the agent's pose [x, y, direction] is the privileged state (`info["pose"]`), which the
oracle reads: a step in the bottom-left corner cells (x <= 2, y >= 3) pays +1 once the agent has
been in the top-right ones (x >= 3, y <= 2) earlier in the episode, else 0. Nothing in one image
says whether the top-right was visited: a reward model must remember it.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

INSTRUCTION = ("The red triangle moves in a small room. Each step it spends in the bottom-left corner "
               "(the two columns on the left, the two rows at the bottom) counts +1, but only once it has "
               "been in the top-right corner (two right columns, two top rows) earlier in the episode. "
               "The return: the number of such steps.")


class _ThreeActions(gym.ActionWrapper):
    """MiniGrid's turn left (0), turn right (1) and forward (2) only."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.action_space = gym.spaces.Discrete(3)

    def action(self, action):
        return int(action)


class _Pose(gym.Wrapper):
    """info["pose"] = [x, y, direction] of the agent (MiniGrid's cell coordinates, y down)."""

    def _pose(self, info: dict) -> dict:
        base = self.env.unwrapped
        return dict(info, pose=np.array([*base.agent_pos, base.agent_dir], dtype=np.float32))

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return obs, self._pose(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._pose(info)


def make_env(size: int = 6, tile_size: int = 8, render_mode: str | None = None) -> gym.Env:
    """MiniGrid-Empty-Random-<size>x<size>: observation the whole room's RGB image
    (size * tile_size square, uint8), three actions, the pose in info["pose"]."""
    import minigrid  # noqa: F401  (registers the MiniGrid environments)
    from minigrid.wrappers import ImgObsWrapper, RGBImgObsWrapper

    env = gym.make(f"MiniGrid-Empty-Random-{size}x{size}-v0", render_mode=render_mode)
    return _Pose(_ThreeActions(ImgObsWrapper(RGBImgObsWrapper(env, tile_size=tile_size))))


def oracle(states: np.ndarray, actions) -> tuple:
    """Poses (T, 3) -> (rewards (T,), hidden (T, 1): the top-right corner visited by step t)."""
    x, y = states[:, 0], states[:, 1]
    visited = np.maximum.accumulate((x >= 3) & (y <= 2)).astype(np.float64)
    rewards = visited * ((x <= 2) & (y >= 3))
    return rewards, visited[:, None]
