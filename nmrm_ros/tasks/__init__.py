"""Task environments (gymnasium, rewardless) and the task registry.

Tasks: the 2D navigation tasks `timer`, `moving`, `key`, `charger` (one simulator, see
`navigation`) and `lunar_lander`; and any Gymnasium environment named by a task spec,
`gym:<id>[,k=v...]` or `<module>:<attribute>[,k=v...]` (`gym_task`). Rewards come from
`nmrm_ros.oracles` or a learnt model.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import gymnasium as gym

from .gym_task import TaskSpecError, is_task_spec, make_gym_task_env

NAVIGATION_TASKS = ("timer", "moving", "key", "charger")
TASKS = NAVIGATION_TASKS + ("lunar_lander",)


@dataclass(frozen=True)
class TaskInfo:
    """Static facts of a task: state size, action space kind and size, episode length T (the
    longest episode, for tasks whose episodes vary in length)."""

    name: str
    state_size: int
    discrete: bool
    action_size: int  # number of discrete actions, or the continuous action dimension
    episode_length: int


def check_task(task: str) -> str:
    """Return `task` if it is one of ours or a usable task spec, else raise ValueError (one line:
    the known tasks, or what is wrong with the spec)."""
    if is_task_spec(task):
        task_info(task)
        return task
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}, or your own "
                         f"environment as gym:<id> or <module>:<attribute>")
    return task


@lru_cache(maxsize=64)
def _spec_info(task: str) -> TaskInfo:
    env = make_gym_task_env(task)
    try:
        act = env.action_space
        discrete = isinstance(act, gym.spaces.Discrete)
        return TaskInfo(task, int(env.observation_space.shape[0]), discrete,
                        int(act.n) if discrete else int(act.shape[0]), env.episode_length)
    finally:
        env.close()


def task_info(task: str) -> TaskInfo:
    if is_task_spec(task):
        return _spec_info(task)
    check_task(task)
    if task == "lunar_lander":
        from .lunar_lander import EPISODE_LENGTH, STATE_SIZE

        return TaskInfo(task, STATE_SIZE, False, 2, EPISODE_LENGTH)
    from .navigation import EPISODE_LENGTH, N_ACTIONS

    return TaskInfo(task, 2, True, N_ACTIONS, EPISODE_LENGTH)


def make_env(task: str, continuous: bool = False, render: bool = False, **kwargs) -> gym.Env:
    """A fresh rewardless env of `task`. `continuous` selects the continuous-action variant of the
    navigation tasks (Lunar Lander is always continuous; a task spec's env has its own actions)."""
    if is_task_spec(task):
        if continuous:
            raise TaskSpecError(f"task {task!r}: continuous applies to the navigation tasks only; "
                                f"a Gymnasium env's action space is its own")
        return make_gym_task_env(task, render=render)
    check_task(task)
    if render and task != "lunar_lander":
        raise TaskSpecError(f"task {task!r} renders no frames (the labelling page draws its arena)")
    if render:
        kwargs["render_mode"] = "rgb_array"
    if task == "lunar_lander":
        from .lunar_lander import RewardlessLunarLander

        return RewardlessLunarLander(**kwargs)
    from .navigation import NavigationEnv

    return NavigationEnv(task=task, continuous=continuous, **kwargs)
