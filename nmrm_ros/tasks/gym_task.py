"""A task from any Gymnasium environment: the task spec, and the rewardless adapter.

A task spec names an environment of the user's, so that nothing in this package has to change
for a new task:

    gym:<id>[,key=value...]              a registered Gymnasium id, e.g. gym:MountainCar-v0,
                                         gym:LunarLanderContinuous-v3,enable_wind=true
    <module>:<attribute>[,key=value...]  an importable env class or factory of the user's own
                                         package, e.g. my_robot.sim:make_env,speed=0.5

`key=value` pairs are keyword arguments of `gym.make` or of the class / factory; values are read
as YAML scalars (`3` int, `0.5` float, `true` bool, else a string). Two keys are ours:
`max_steps=N` ends episodes after N steps (a TimeLimit) where the environment has no limit of
its own; without either, the task is refused, since MIL needs whole trajectories. `xy=i/j` names
the state dimensions the labelling page draws as a 2D path (e.g. a robot's position).

What the package sees of the environment (`GymTaskEnv`):
- the state: the observation flattened to a float32 vector (`gymnasium.spaces.flatten`: a Box
  as is, a Discrete / MultiBinary / MultiDiscrete one-hot, Tuple and Dict concatenated); spaces
  that have no fixed-size flattening (Text, Graph, Sequence) are refused;
- the actions: Discrete(n) or a 1-D Box, as the environment has them;
- no reward: the environment's own reward is not what is learnt; it is kept in
  `info["env_reward"]` for comparison only.
Episodes end when the environment terminates or truncates, so they may vary in length; the
task's `episode_length` is their maximum.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import yaml

GYM_PREFIX = "gym:"


class TaskSpecError(ValueError):
    """A task spec that does not name a usable environment (one line, says why)."""


def is_task_spec(task: str) -> bool:
    """Whether `task` is a spec of a user's environment (it has a colon) rather than a task name."""
    return ":" in task


@dataclass(frozen=True)
class TaskSpec:
    """A parsed task spec: `kind` "gym" (registered id) or "import" (module:attribute)."""

    text: str
    kind: str
    target: str  # the Gymnasium id, or "module:attribute"
    kwargs: dict = field(default_factory=dict)
    max_steps: int | None = None
    xy: tuple | None = None  # state dimensions the labelling page draws as a 2D path


def parse_task_spec(text: str) -> TaskSpec:
    """Parse `gym:<id>[,k=v...]` or `<module>:<attribute>[,k=v...]`; TaskSpecError if malformed."""
    head, *pairs = [p.strip() for p in text.strip().split(",")]
    kwargs: dict = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        if not eq or not key.strip().isidentifier():
            raise TaskSpecError(f"task {text!r}: {pair!r} is not key=value")
        try:
            kwargs[key.strip()] = yaml.safe_load(value) if value.strip() else ""
        except yaml.YAMLError:
            kwargs[key.strip()] = value
    max_steps = kwargs.pop("max_steps", None)
    if max_steps is not None and (not isinstance(max_steps, int) or isinstance(max_steps, bool)
                                  or max_steps < 1):
        raise TaskSpecError(f"task {text!r}: max_steps must be a positive integer, got {max_steps!r}")
    xy = kwargs.pop("xy", None)
    if xy is not None:
        try:
            i, j = (int(v) for v in str(xy).split("/"))
            if i < 0 or j < 0 or i == j:
                raise ValueError
        except ValueError:
            raise TaskSpecError(f"task {text!r}: xy must name two state dimensions as i/j, e.g. xy=0/1, "
                                f"got {xy!r}") from None
        xy = (i, j)
    if head.startswith(GYM_PREFIX):
        target = head[len(GYM_PREFIX):]
        if not target:
            raise TaskSpecError(f"task {text!r}: give a Gymnasium id after gym:, e.g. gym:MountainCar-v0")
        return TaskSpec(text, "gym", target, kwargs, max_steps, xy)
    module, _, attribute = head.partition(":")
    if not module or not attribute:
        raise TaskSpecError(f"task {text!r}: use gym:<id> or <module>:<attribute>")
    return TaskSpec(text, "import", head, kwargs, max_steps, xy)


def _construct(spec: TaskSpec, render: bool = False) -> gym.Env:
    """The user's environment as they made it (not yet adapted); `render`: with
    render_mode="rgb_array", so that `render()` returns frames."""
    kwargs = dict(spec.kwargs, render_mode="rgb_array") if render else spec.kwargs
    if spec.kind == "gym":
        try:
            return gym.make(spec.target, **kwargs)
        except Exception as exc:  # an unknown id, a missing dependency, the env's own error
            raise TaskSpecError(f"task {spec.text!r}: {' '.join(str(exc).split())}") from None
    module_name, _, attribute = spec.target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TaskSpecError(f"task {spec.text!r}: cannot import {module_name!r} ({exc})") from None
    factory = module
    for part in attribute.split("."):
        factory = getattr(factory, part, None)
        if factory is None:
            raise TaskSpecError(f"task {spec.text!r}: module {module_name!r} has no {attribute!r}")
    if not callable(factory):
        raise TaskSpecError(f"task {spec.text!r}: {attribute!r} is not an env class or factory")
    try:
        env = factory(**kwargs)
    except TypeError as exc:
        if render and "render_mode" in str(exc):
            raise TaskSpecError(f"task {spec.text!r}: {attribute}(...) takes no render_mode, so it "
                                f"cannot render frames") from None
        raise TaskSpecError(f"task {spec.text!r}: {attribute}(...) failed: "
                            f"TypeError: {' '.join(str(exc).split())}") from None
    except Exception as exc:  # the user's code: say whose error it is, in one line
        raise TaskSpecError(f"task {spec.text!r}: {attribute}(...) failed: "
                            f"{type(exc).__name__}: {' '.join(str(exc).split())}") from None
    if not isinstance(env, gym.Env):
        raise TaskSpecError(f"task {spec.text!r}: {attribute}(...) returned a "
                            f"{type(env).__name__}, not a gymnasium.Env")
    return env


def _episode_limit(env: gym.Env) -> int | None:
    """The env's own step limit (its TimeLimit / spec), or None."""
    limit = getattr(env.spec, "max_episode_steps", None) if env.spec is not None else None
    inner = env
    while limit is None and isinstance(inner, gym.Wrapper):
        if isinstance(inner, gym.wrappers.TimeLimit):
            limit = inner._max_episode_steps
        inner = inner.env
    return limit


def _check_spaces(env: gym.Env, spec: TaskSpec) -> None:
    obs, act = env.observation_space, env.action_space
    try:
        size = gym.spaces.flatdim(obs)
    except (ValueError, NotImplementedError, TypeError):
        raise TaskSpecError(f"task {spec.text!r}: observation space {obs} has no fixed-size "
                            f"flattening (use Box, Discrete, MultiBinary, MultiDiscrete, Tuple or Dict)") from None
    if size < 1:
        raise TaskSpecError(f"task {spec.text!r}: the observation space {obs} is empty")
    if isinstance(act, gym.spaces.Discrete):
        return
    if isinstance(act, gym.spaces.Box) and len(act.shape) == 1:
        return
    raise TaskSpecError(f"task {spec.text!r}: action space {act} is neither Discrete nor a 1-D Box")


class GymTaskEnv(gym.Wrapper):
    """A user's env as a task: flattened float32 states, no reward (kept as info["env_reward"]),
    episodes of at most `episode_length` steps (the env's limit or `max_steps`)."""

    def __init__(self, env: gym.Env, spec: TaskSpec) -> None:
        _check_spaces(env, spec)
        limit = _episode_limit(env)
        if spec.max_steps is not None and (limit is None or spec.max_steps < limit):
            env = gym.wrappers.TimeLimit(env, spec.max_steps)
            limit = spec.max_steps
        if limit is None:
            raise TaskSpecError(f"task {spec.text!r}: the environment has no episode limit; add "
                                f"max_steps=N to the task (e.g. {spec.text.split(',')[0]},max_steps=500)")
        super().__init__(env)
        self.task = spec.text
        self.episode_length = int(limit)
        self._source_space = env.observation_space
        size = gym.spaces.flatdim(self._source_space)
        if spec.xy is not None and max(spec.xy) >= size:
            raise TaskSpecError(f"task {spec.text!r}: xy={spec.xy[0]}/{spec.xy[1]} but the state has "
                                f"{size} dimensions (0..{size - 1})")
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
        self._t = 0

    def _flat(self, obs) -> np.ndarray:
        return np.asarray(gym.spaces.flatten(self._source_space, obs), dtype=np.float32).reshape(-1)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._t = 0
        return self._flat(obs), dict(info, t=0)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._t += 1
        info = dict(info, t=self._t, env_reward=float(reward))
        return self._flat(obs), 0.0, bool(terminated), bool(truncated), info


def make_gym_task_env(task: str, render: bool = False) -> GymTaskEnv:
    """The env of task spec `task` (see the module docstring); TaskSpecError if it is unusable.
    `render`: made with render_mode="rgb_array" (`env.render()` returns an RGB frame)."""
    spec = parse_task_spec(task)
    return GymTaskEnv(_construct(spec, render), spec)
