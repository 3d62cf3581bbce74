"""A LeRobot dataset as a task of its own: `lerobot:<dir>[,state=KEY,action=KEY,xy=i/j]`.

A dataset someone recorded with LeRobot has no task module of ours and often no simulator: its
task is the dataset itself. The spec names the dataset's directory; what the package knows of the
task (`TaskInfo`) is read from the dataset's metadata:

    state_size       the width of the state feature (`state`, default observation.state)
    action_size      the width of the action feature (`action`, default action; 0 if it has none);
                     actions are continuous (LeRobot keeps them as float vectors)
    episode_length   the longest episode's steps (frames - 1: its last frame is its final state)
    instruction      the dataset's task text(s) (meta/tasks.parquet), shown to people labelling it

Such a task has no environment (`make_env` is a one-line error naming what to do instead), no
oracle, no renderer: its episodes come from `nmrm import lerobot`, its frames from the dataset's
camera, its labels from people, a labeller's file or a reward column. The bag records the spec
with the dataset's absolute path, so the dataset must stay where it was imported from: training,
the page, serving the model and exporting read its metadata.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from ..tasks.gym_task import LEROBOT_PREFIX, TaskSpec, TaskSpecError
from ..tasks.info import TaskInfo
from .format import LeRobotError, read_episode_rows, read_info, read_tasks, vector_width

DEFAULT_STATE = "observation.state"
DEFAULT_ACTION = "action"
MAX_INSTRUCTION = 500  # characters of the task texts shown as what to judge


def dataset_task_spec(root: str | Path, state_key: str = DEFAULT_STATE, action_key: str | None = DEFAULT_ACTION) -> str:
    """The task spec of the dataset at `root` read with these keys, e.g. "lerobot:/data/pick" (the
    absolute path); LeRobotError if the path cannot be written into a spec (a comma)."""
    text = str(Path(root).resolve())  # the bag, the checkpoint and an export record it: any working directory
    if "," in text:
        raise LeRobotError(f"{text}: a path with a comma cannot name a task; give --task, or move the dataset")
    spec = LEROBOT_PREFIX + text
    if state_key != DEFAULT_STATE:
        spec += f",state={state_key}"
    if action_key != DEFAULT_ACTION:
        spec += f",action={action_key or ''}"  # action= : none
    return spec


@lru_cache(maxsize=16)
def _dataset_task_info(text: str, root: str, state_key: str, action_key: str, xy: tuple | None) -> TaskInfo:
    path = Path(root)
    try:
        info = read_info(path)
        features = info["features"]
        if state_key not in features:
            raise LeRobotError(f"no state feature {state_key!r} (its features: {', '.join(features)})")
        state_size = vector_width(features[state_key], state_key)
        action_size = vector_width(features[action_key], action_key) if action_key in features else 0
        lengths = [int(r["length"]) for r in read_episode_rows(path)]
        texts = read_tasks(path)
    except LeRobotError as exc:
        raise TaskSpecError(f"task {text!r}: {exc}") from None
    except (TypeError, AttributeError, KeyError, ValueError) as exc:  # metadata of the wrong shape
        raise TaskSpecError(f"task {text!r}: the dataset's metadata is malformed ({type(exc).__name__}: {exc})") from None
    if not lengths or max(lengths) < 2:
        raise TaskSpecError(f"task {text!r}: the dataset has no episode of two frames or more")
    if xy is not None and max(xy) >= state_size:
        raise TaskSpecError(f"task {text!r}: xy={xy[0]}/{xy[1]} but the state has {state_size} values")
    instruction = " / ".join(" ".join(str(t).split()) for t in texts)
    if len(instruction) > MAX_INSTRUCTION:  # a dataset with a text per episode: the page shows the start
        instruction = instruction[:MAX_INSTRUCTION - 3].rstrip() + "..."
    return TaskInfo(text, state_size, False, action_size, max(lengths) - 1, instruction=instruction)


def dataset_task_info(spec: TaskSpec) -> TaskInfo:
    """The TaskInfo of a parsed `lerobot:` spec, from the dataset's metadata; TaskSpecError (one
    line) if the dataset is missing, of another version, or lacks the named features."""
    state_key = str(spec.kwargs.get("state", DEFAULT_STATE))
    action_key = str(spec.kwargs.get("action", DEFAULT_ACTION))
    return _dataset_task_info(spec.text, spec.target, state_key, action_key, spec.xy)
