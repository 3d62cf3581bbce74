"""Task environments (gymnasium, rewardless) and the task registry.

Tasks: the 2D navigation tasks `timer`, `moving`, `key`, `charger` (one simulator, see
`navigation`) and `lunar_lander`. Rewards come from `nmrm_ros.oracles` or a learnt model.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym

NAVIGATION_TASKS = ("timer", "moving", "key", "charger")
TASKS = NAVIGATION_TASKS + ("lunar_lander",)


@dataclass(frozen=True)
class TaskInfo:
    """Static facts of a task: state size, action space kind and size, episode length T."""

    name: str
    state_size: int
    discrete: bool
    action_size: int  # number of discrete actions, or the continuous action dimension
    episode_length: int


def check_task(task: str) -> str:
    """Return `task` if known, else raise ValueError naming the known tasks."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
    return task


def task_info(task: str) -> TaskInfo:
    check_task(task)
    if task == "lunar_lander":
        from .lunar_lander import EPISODE_LENGTH, STATE_SIZE

        return TaskInfo(task, STATE_SIZE, False, 2, EPISODE_LENGTH)
    from .navigation import EPISODE_LENGTH, N_ACTIONS

    return TaskInfo(task, 2, True, N_ACTIONS, EPISODE_LENGTH)


def make_env(task: str, continuous: bool = False, **kwargs) -> gym.Env:
    """A fresh rewardless env of `task`. `continuous` selects the continuous-action variant of the
    navigation tasks (Lunar Lander is always continuous)."""
    check_task(task)
    if task == "lunar_lander":
        from .lunar_lander import RewardlessLunarLander

        return RewardlessLunarLander(**kwargs)
    from .navigation import NavigationEnv

    return NavigationEnv(task=task, continuous=continuous, **kwargs)
