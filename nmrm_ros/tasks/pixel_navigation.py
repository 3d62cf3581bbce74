"""Pixel versions of the navigation tasks: the model sees a rendered top-down image, not [x, y].

Task `<t>_pixels` for t in timer, moving, key, charger: the same simulator, screened episodes and
oracle as task t, but the state is a top-down RGB image of the room (`IMAGE_SIZE` x `IMAGE_SIZE`
x 3, values 0..255) flattened row-major (H, W, C) — `TaskInfo.image_shape` says how to view it —
and the true position [x, y] is *privileged* state: kept beside the episode and given to the
oracle (and the plots), never to a reward model or an agent.

The image shows what the state task's model sees and nothing more: the zones (static, drawn as
`navigation.map_zones` colours them) and the agent as a small blob (a Gaussian of `AGENT_SIGMA`
pixels, so that its position is readable to a fraction of a pixel). Row 0 is the top (y = 1).
A pixel dataset is the state task's screened dataset of the same data seed, rendered
(`pixel_dataset`): the same episodes and labels, so a pixel model and a state model are
compared on exactly the same data.
"""

from __future__ import annotations

from functools import lru_cache

import gymnasium as gym
import numpy as np

from .navigation import EPISODE_LENGTH, NavigationEnv, map_zones

#: the suffix that names a navigation task's pixel version, e.g. key_pixels
PIXEL_SUFFIX = "_pixels"
#: the side of the rendered image, in pixels (32: the arena's 0.1-wide zones span ~3 pixels)
IMAGE_SIZE = 32
#: the agent blob's standard deviation, in pixels
AGENT_SIGMA = 0.8
AGENT_COLOUR = np.array([255.0, 40.0, 40.0])
BACKGROUND = np.array([30.0, 30.0, 30.0])
#: how strongly a zone's colour covers the background (the agent is drawn over both)
ZONE_ALPHA = 0.6
#: rendered at most this many images at a time (memory: ~12 KB of float64 each at 32 x 32)
_CHUNK = 4096


def base_task(task: str) -> str:
    """The state task of a pixel task name (key_pixels -> key); ValueError for any other name."""
    if not task.endswith(PIXEL_SUFFIX):
        raise ValueError(f"{task!r} is not a pixel task (<task>{PIXEL_SUFFIX})")
    return task[: -len(PIXEL_SUFFIX)]


@lru_cache(maxsize=16)
def background(task: str, size: int = IMAGE_SIZE) -> np.ndarray:
    """The room of state task `task` without the agent, (size, size, 3) float64 in 0..255."""
    from matplotlib.colors import to_rgb

    image = np.tile(BACKGROUND, (size, size, 1))
    centres = (np.arange(size) + 0.5) / size
    xs, ys = centres[None, :], 1.0 - centres[:, None]  # pixel (i, j) -> (x_j, y_i)
    for zone in map_zones(task):
        inside = (xs >= zone.x_min) & (xs <= zone.x_max) & (ys >= zone.y_min) & (ys <= zone.y_max)
        colour = 255.0 * np.array(to_rgb(zone.colour))
        image[inside] = (1 - ZONE_ALPHA) * image[inside] + ZONE_ALPHA * colour
    return image


def render_positions(task: str, positions: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """Images of the agent at `positions` (..., 2) in state task `task`'s room: (..., size, size,
    3) uint8."""
    positions = np.asarray(positions, dtype=np.float64)
    lead = positions.shape[:-1]
    flat = positions.reshape(-1, 2)
    out = np.empty((len(flat), size, size, 3), dtype=np.uint8)
    room = background(task, size)
    grid = np.arange(size) + 0.5
    for start in range(0, len(flat), _CHUNK):
        p = flat[start:start + _CHUNK]
        ax = np.exp(-0.5 * ((grid[None, :] - p[:, :1] * size) / AGENT_SIGMA) ** 2)  # (n, W)
        ay = np.exp(-0.5 * ((grid[None, :] - (1.0 - p[:, 1:2]) * size) / AGENT_SIGMA) ** 2)  # (n, H)
        alpha = (ay[:, :, None] * ax[:, None, :])[..., None]  # (n, H, W, 1)
        image = (1.0 - alpha) * room + alpha * AGENT_COLOUR
        out[start:start + len(p)] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return out.reshape(*lead, size, size, 3)


def pixel_states(task: str, positions: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """The states of pixel task `<task>_pixels` at `positions` (..., 2): (..., size * size * 3)
    uint8 (the image, flattened row-major)."""
    images = render_positions(task, positions, size)
    return images.reshape(*images.shape[:-3], size * size * 3)


def pixel_task_info(task: str):
    """The TaskInfo of pixel task `task` (e.g. key_pixels): the state task's, with an image state,
    the position as privileged state, and no 2D map of states (the views draw none yet)."""
    from dataclasses import replace

    from .navigation import navigation_task_info

    base = navigation_task_info(base_task(task))
    return replace(base, name=task, state_size=IMAGE_SIZE * IMAGE_SIZE * 3, arena=None, classify=None,
                   screening_classes=None, navigation=False, zones=(), map_states=None, renders=True,
                   image_shape=(IMAGE_SIZE, IMAGE_SIZE, 3), privileged_size=2, pixels_of=base.name)


def pixel_dataset(ds, task: str):
    """The pixel version of a state task's dataset `ds` (the same episodes, labels and meta):
    states rendered to images (uint8), the positions kept as `privileged` states."""
    from dataclasses import replace

    base = base_task(task)
    if ds.task != base:
        raise ValueError(f"a {task} dataset is rendered from a {base} dataset, not {ds.task}")
    n, L, _ = ds.states.shape
    states = pixel_states(base, ds.states)
    mask = np.arange(L)[None, :] < ds.lengths[:, None]
    states[~mask] = 0  # padding stays zero
    final = None if ds.final_states is None else pixel_states(base, ds.final_states)
    privileged = ds.states.astype(np.float32)
    meta = dict(ds.meta, rendered={"from": base, "size": IMAGE_SIZE, "sigma": AGENT_SIGMA})
    return replace(ds, task=task, states=states, final_states=final, meta=meta, privileged=privileged)


class PixelNavigationEnv(gym.Env):
    """A navigation task seen through its top-down image: observations are the flattened image
    (IMAGE_SIZE * IMAGE_SIZE * 3,) float32 in 0..255; `info["privileged"]` is the true position
    [x, y]; no reward (as `NavigationEnv`)."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, task: str = "key_pixels", episode_length: int = EPISODE_LENGTH,
                 render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be rgb_array or None, got {render_mode!r}")
        self.render_mode = render_mode
        self._image = None
        self.task = task
        self.base = base_task(task)
        self._env = NavigationEnv(task=self.base, episode_length=episode_length)
        self.episode_length = self._env.episode_length
        self.action_space = self._env.action_space
        self.observation_space = gym.spaces.Box(0.0, 255.0, shape=(IMAGE_SIZE * IMAGE_SIZE * 3,), dtype=np.float32)

    def _observe(self, position: np.ndarray, info: dict):
        image = pixel_states(self.base, position)
        self._image = image
        return image.astype(np.float32), dict(info, privileged=np.asarray(position, dtype=np.float32))

    def render(self) -> np.ndarray | None:
        """The current observation as an RGB frame (`frames.image_state_frame`: 128 x 128, uint8):
        what the model sees, enlarged without smoothing; None without render_mode "rgb_array"."""
        from .frames import image_state_frame

        if self.render_mode != "rgb_array" or self._image is None:
            return None
        return image_state_frame(self._image, (IMAGE_SIZE, IMAGE_SIZE, 3))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        position, info = self._env.reset(seed=seed, options=options)
        return self._observe(position, info)

    def step(self, action):
        position, reward, terminated, truncated, info = self._env.step(action)
        state, info = self._observe(position, info)
        return state, reward, terminated, truncated, info
