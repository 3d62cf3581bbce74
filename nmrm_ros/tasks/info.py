"""`TaskInfo`: the one object that carries what the package knows of a task.

Every per-task fact lives here or in the task's own module, which builds its TaskInfo
(`navigation.navigation_task_info`, `lunar_lander.TASK_INFO`, `gym_task` for a user's
environment); the rest of the package asks `task_info(task)` (`nmrm_ros.tasks`) and branches on
its fields, never on a task's name. Fields: the state layout and actions, the reward models'
layer-size family, the returns a person may label, the 2D map (arena) the views draw, how a
screened dataset is built (and the class rule of a class-screened task), whether the env renders
frames, whether it is one of the navigation tasks (continuous variant, the demo), the zones
the views draw on its map, and what a person labelling it is asked to judge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class ScreeningSpec:
    """Per-class limits of a class-screened task (paper App. D.2): `limits[c]` is the max fraction
    of the dataset for class c, or `default`."""

    n_classes: int
    default: float
    limits: dict | None = None

    def max_count(self, cls: int, n_target: int) -> int:
        p = self.default if self.limits is None else self.limits.get(cls, self.default)
        return max(1, math.ceil(p * n_target - 1e-9))


#: how a task's screened dataset is made: "classes" (random rollouts kept under per-class limits,
#: `datasets.screen_navigation`), "pool" (a pool of scripted and agent rollouts screened by class,
#: `datasets.screen_lunar_lander`), "return_bins" (your own task: rollouts kept under per-return-bin
#: limits, `datasets.return_screening`)
SCREENINGS = ("classes", "pool", "return_bins")


@dataclass(frozen=True)
class MapZone:
    """A zone the views draw on a task's map, in state coordinates s[0], s[1]: a rectangle
    (style "box", or "dashed"), or a thick line along its bottom edge ("bar", e.g. a landing pad);
    label: its legend entry (None: unlabelled, e.g. a second zone of the same kind)."""

    label: str | None
    colour: str
    x_min: float
    x_max: float
    y_min: float
    y_max: float
    style: str = "box"


@dataclass(frozen=True)
class TaskInfo:
    """What the package knows of a task.

    name; state_size (d of s_t); discrete (actions are indices) and action_size (number of
    discrete actions, or the continuous action dimension); episode_length (T, the longest
    episode); family: the layer widths of its reward models (`mil.models.FAMILY_SIZES`;
    "toy" for a user's task unless its training config says otherwise); return_range: (low,
    high) a person's return label may take ((None, None): any finite number); arena: (x_min,
    x_max, y_min, y_max) of the 2D map the views draw in state coordinates s[0], s[1] (None: no
    map); screening: one of SCREENINGS; screening_classes(key_fourth_class) -> ScreeningSpec and
    classify(states (n, L, d), labels, key_fourth_class) -> class ids (n,): the class rule of a
    task screened by class (None otherwise); renders: the env draws RGB frames; navigation: one of
    the 2D navigation tasks (a continuous-action variant, `nmrm demo`); map_states: the state at
    each map point (N, 2) -> (N, d) when d > 2 (`states_at`), and what the views say of it (map_note);
    map_name: what the map is called in a figure's title; zones: the `MapZone`s drawn on it;
    instruction: what a person judges, in words (the labelling page shows it; "" = none written);
    legend: (zone kind, what it means) pairs for the zones the page draws (`arena.arena`);
    image_shape: (H, W, C) when the state's first H*W*C values are an image's pixels (0..255,
    row-major H, W, C; a reward model puts an image encoder in front of them), () for a vector
    state; privileged_size: the size of the privileged state (what the oracle and the plots see,
    a model or an agent never: e.g. the true position behind a camera image), 0 for none;
    pixels_of: the vector-state task whose pixel version this is (its datasets rendered, its
    oracle on the privileged state), "" otherwise; encoder_image_shape: (H, W, C) of the image a
    task spec's frozen encoder reads (`encoder=`; its features lead the state, and image_shape is
    ()), () without one."""

    name: str
    state_size: int
    discrete: bool
    action_size: int
    episode_length: int
    family: str = "toy"
    return_range: tuple = (None, None)
    arena: tuple | None = None
    screening: str = "return_bins"
    screening_classes: Callable | None = None
    classify: Callable | None = None
    renders: bool = False
    navigation: bool = False
    map_states: Callable | None = None
    map_note: str = ""
    map_name: str = "arena"
    zones: tuple = ()
    instruction: str = ""
    legend: tuple = ()
    image_shape: tuple = ()
    privileged_size: int = 0
    pixels_of: str = ""
    encoder_image_shape: tuple = ()

    @property
    def image_values(self) -> int:
        """How many leading state values are pixels (H*W*C; 0 for a vector state)."""
        return int(math.prod(self.image_shape)) if self.image_shape else 0

    def states_at(self, points):
        """The states the views draw at 2D map points (N, 2) -> (N, state_size) (`map_states`;
        without one, the points themselves)."""
        return points if self.map_states is None else self.map_states(points)
