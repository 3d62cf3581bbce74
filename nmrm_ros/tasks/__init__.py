"""Task environments (gymnasium, rewardless) and the task registry.

Tasks: the 2D navigation tasks `timer`, `moving`, `key`, `charger` (one simulator, see
`navigation`), their pixel versions `<task>_pixels` (the state is a rendered top-down image, the
position privileged: `pixel_navigation`) and `lunar_lander`; and any Gymnasium environment named by a task spec,
`gym:<id>[,k=v...]` or `<module>:<attribute>[,k=v...]` (`gym_task`), or a recorded LeRobot
dataset with no environment, `lerobot:<dir>` (`nmrm_ros.lerobot.dataset_task`). Rewards come from
`nmrm_ros.oracles` or a learnt model.
"""

from __future__ import annotations

from functools import lru_cache

import gymnasium as gym

from .gym_task import TaskSpecError, is_task_spec, make_gym_task_env, parse_task_spec
from .info import TaskInfo

NAVIGATION_TASKS = ("timer", "moving", "key", "charger")
PIXEL_TASKS = tuple(f"{t}_pixels" for t in NAVIGATION_TASKS)
TASKS = NAVIGATION_TASKS + ("lunar_lander",) + PIXEL_TASKS


def check_task(task: str) -> str:
    """Return `task` if it is one of ours or a usable task spec, else raise ValueError (one line:
    the known tasks, or what is wrong with the spec)."""
    if is_task_spec(task):
        task_info(task)
        return task
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}, or your own "
                         f"environment as gym:<id> or <module>:<attribute>, or a LeRobot dataset as lerobot:<dir>")
    return task


@lru_cache(maxsize=64)
def _spec_info(task: str) -> TaskInfo:
    env = make_gym_task_env(task)
    try:
        act = env.action_space
        discrete = isinstance(act, gym.spaces.Discrete)
        instruction, legend = _module_words(task)
        privileged = 0
        if env.spec_.privileged is not None:  # its size: that of the first reset's
            privileged = int(env.reset(seed=0)[1]["privileged"].size)
        return TaskInfo(task, int(env.observation_space.shape[0]), discrete,
                        int(act.n) if discrete else int(act.shape[0]), env.episode_length, renders=True,
                        instruction=instruction, legend=legend, image_shape=env.image_shape,
                        privileged_size=privileged,
                        encoder_image_shape=env.layout.image_shape if env.encoder is not None else ())
    finally:
        env.close()


def _module_words(task: str) -> tuple:
    """(instruction, legend) a user's task module gives: its `INSTRUCTION` text (what a person
    judges) and the `legend` of its `ARENA` ({zone kind: meaning}); ("", ()) where it gives none."""
    import importlib

    spec = parse_task_spec(task)
    if spec.kind != "import":
        return "", ()
    module = importlib.import_module(spec.target.split(":")[0])
    instruction = getattr(module, "INSTRUCTION", "")
    legend = (getattr(module, "ARENA", None) or {}).get("legend", {})
    if not isinstance(instruction, str) or not isinstance(legend, dict):
        raise TaskSpecError(f"{spec.target.split(':')[0]}: INSTRUCTION must be a str and ARENA['legend'] a dict "
                            f"of zone kind -> meaning")
    return " ".join(instruction.split()), tuple((str(k), str(v)) for k, v in legend.items())


def has_environment(task: str) -> bool:
    """Whether `task` has an environment to run (a recorded dataset, `lerobot:<dir>`, has none)."""
    return not (is_task_spec(task) and parse_task_spec(task).kind == "lerobot")


def task_info(task: str) -> TaskInfo:
    """What the package knows of `task` (`TaskInfo`: state layout, actions, model family, label
    range, arena, screening rule, frames); ValueError (one line) for an unknown task."""
    if is_task_spec(task):
        spec = parse_task_spec(task)
        if spec.kind == "lerobot":  # a recorded dataset, no environment
            from ..lerobot.dataset_task import dataset_task_info

            return dataset_task_info(spec)
        return _spec_info(task)
    check_task(task)
    if task in NAVIGATION_TASKS:
        from .navigation import navigation_task_info

        return navigation_task_info(task)
    if task in PIXEL_TASKS:
        from .pixel_navigation import pixel_task_info

        return pixel_task_info(task)
    from .lunar_lander import TASK_INFO

    return TASK_INFO


def make_env(task: str, continuous: bool = False, render: bool = False, **kwargs) -> gym.Env:
    """A fresh rewardless env of `task`. `continuous` selects the continuous-action variant of the
    navigation tasks (Lunar Lander is always continuous; a task spec's env has its own actions)."""
    if is_task_spec(task):
        if continuous:
            raise TaskSpecError(f"task {task!r}: continuous applies to the navigation tasks only; "
                                f"a Gymnasium env's action space is its own")
        return make_gym_task_env(task, render=render)
    info = task_info(task)
    if render and not info.renders:
        raise TaskSpecError(f"task {task!r} renders no frames (the labelling page draws its arena)")
    if render:
        kwargs["render_mode"] = "rgb_array"
    if info.navigation:
        from .navigation import NavigationEnv

        return NavigationEnv(task=task, continuous=continuous, **kwargs)
    if info.pixels_of:
        if continuous:
            raise TaskSpecError(f"task {task!r}: the pixel tasks have discrete actions only")
        from .pixel_navigation import PixelNavigationEnv

        return PixelNavigationEnv(task=task, **kwargs)
    from .lunar_lander import RewardlessLunarLander

    return RewardlessLunarLander(**kwargs)
