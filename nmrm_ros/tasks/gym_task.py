"""A task from any Gymnasium environment: the task spec, and the rewardless adapter.

A task spec names an environment of the user's, so that nothing in this package has to change
for a new task:

    gym:<id>[,key=value...]              a registered Gymnasium id, e.g. gym:MountainCar-v0,
                                         gym:LunarLanderContinuous-v3,enable_wind=true
    <module>:<attribute>[,key=value...]  an importable env class or factory of the user's own
                                         package, e.g. my_robot.sim:make_env,speed=0.5
    lerobot:<dir>[,state=K,action=K]     a LeRobot dataset on disk, as a task without an
                                         environment (`nmrm_ros.lerobot.dataset_task`): its
                                         episodes can be labelled, modelled and exported, not run

`key=value` pairs are keyword arguments of `gym.make` or of the class / factory; values are read
as YAML scalars (`3` int, `0.5` float, `true` bool, else a string). Four keys are ours:
`max_steps=N` ends episodes after N steps (a TimeLimit) where the environment has no limit of
its own; without either, the task is refused, since MIL needs whole trajectories. `xy=i/j` names
the state dimensions the labelling page draws as a 2D path (e.g. a robot's position).
`image=HxW` resizes the observation's images to H x W pixels (bilinear). `privileged=<key>` names
the entry of the env's `info` that is its privileged state (e.g. the simulator's true positions
behind a camera image): the oracle labels and judges with it, a model and an agent never see it.
`encoder=<module>:<attribute>[,encoder_weights=<path>]` puts a user's own image encoder, frozen, in
front of the state: the image's part of the state is then its features, computed once per frame
(`nmrm_ros.tasks.frozen_encoder`), and the task is a vector task.

What the package sees of the environment (`GymTaskEnv`):
- the state: the observation flattened to a float32 vector (`gymnasium.spaces.flatten`: a Box
  as is, a Discrete / MultiBinary / MultiDiscrete one-hot, Tuple and Dict concatenated); spaces
  that have no fixed-size flattening (Text, Graph, Sequence) are refused. An image (a uint8 Box
  H x W x C with C 1, 3 or 4, or H x W) — the observation, or entries of a Dict observation —
  comes first, as its pixels (0..255, row-major H, W, C; several images resized to one size and
  stacked along C), then the rest flattened: `TaskInfo.image_shape` says so, and a reward model
  reads it through its image encoder (`nmrm_ros.mil.image_encoder`);
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
LEROBOT_PREFIX = "lerobot:"


class TaskSpecError(ValueError):
    """A task spec that does not name a usable environment (one line, says why)."""


def is_task_spec(task: str) -> bool:
    """Whether `task` is a spec of a user's environment (it has a colon) rather than a task name."""
    return ":" in task


@dataclass(frozen=True)
class TaskSpec:
    """A parsed task spec: `kind` "gym" (registered id), "import" (module:attribute) or
    "lerobot" (a dataset directory: no environment)."""

    text: str
    kind: str
    target: str  # the Gymnasium id, "module:attribute", or the LeRobot dataset's directory
    kwargs: dict = field(default_factory=dict)
    max_steps: int | None = None
    xy: tuple | None = None  # state dimensions the labelling page draws as a 2D path
    image: tuple | None = None  # (H, W) the observation's images are resized to
    privileged: str | None = None  # the info entry that is the privileged state
    encoder: str | None = None  # <module>:<attribute> of a frozen image encoder (frozen_encoder)
    encoder_weights: str | None = None  # the state dict it loads


def parse_task_spec(text: str) -> TaskSpec:
    """Parse `gym:<id>[,k=v...]`, `<module>:<attribute>[,k=v...]` or `lerobot:<dir>[,k=v...]`;
    TaskSpecError if malformed."""
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
        xy = _int_pair(text, xy, "/", lambda i, j: i >= 0 and j >= 0 and i != j,
                       "xy must name two state dimensions as i/j, e.g. xy=0/1")
    image = kwargs.pop("image", None)
    if image is not None:
        image = _int_pair(text, image, "x", lambda h, w: h >= 1 and w >= 1,
                          "image must be a size HxW in pixels, e.g. image=64x64")
    privileged = kwargs.pop("privileged", None)
    if privileged is not None and (not isinstance(privileged, str) or not privileged):
        raise TaskSpecError(f"task {text!r}: privileged must name an entry of the env's info, got {privileged!r}")
    encoder, encoder_weights = kwargs.pop("encoder", None), kwargs.pop("encoder_weights", None)
    if encoder is not None and (not isinstance(encoder, str) or ":" not in encoder):
        raise TaskSpecError(f"task {text!r}: encoder must be <module>:<attribute> of an image encoder, got {encoder!r}")
    if encoder_weights is not None and encoder is None:
        raise TaskSpecError(f"task {text!r}: encoder_weights without encoder=<module>:<attribute>")
    if encoder_weights is not None and (not isinstance(encoder_weights, str) or not encoder_weights):
        raise TaskSpecError(f"task {text!r}: encoder_weights must be a file's path, got {encoder_weights!r}")
    extra = {"image": image, "privileged": privileged, "encoder": encoder, "encoder_weights": encoder_weights}
    if head.startswith(LEROBOT_PREFIX):
        target = head[len(LEROBOT_PREFIX):]
        for pair in pairs:  # feature names as written (not YAML: state=true is the feature "true")
            key, _, value = pair.partition("=")
            if key.strip() in ("state", "action"):
                kwargs[key.strip()] = value.strip()
        unknown = sorted(set(kwargs) - {"state", "action"}) + [k for k, v in (("max_steps", max_steps),
                                                                              ("image", image),
                                                                              ("privileged", privileged),
                                                                              ("encoder", encoder)) if v]
        if not target:
            raise TaskSpecError(f"task {text!r}: give a LeRobot dataset's directory after lerobot:")
        if unknown:
            raise TaskSpecError(f"task {text!r}: a LeRobot dataset task takes state=KEY, action=KEY and xy=i/j, "
                                f"not {unknown[0]}")
        return TaskSpec(text, "lerobot", target, kwargs, None, xy)
    if head.startswith(GYM_PREFIX):
        target = head[len(GYM_PREFIX):]
        if not target:
            raise TaskSpecError(f"task {text!r}: give a Gymnasium id after gym:, e.g. gym:MountainCar-v0")
        return TaskSpec(text, "gym", target, kwargs, max_steps, xy, **extra)
    module, _, attribute = head.partition(":")
    if not module or not attribute:
        raise TaskSpecError(f"task {text!r}: use gym:<id> or <module>:<attribute>")
    return TaskSpec(text, "import", head, kwargs, max_steps, xy, **extra)


def _int_pair(text: str, value, sep: str, valid, what: str) -> tuple:
    """Two integers "a<sep>b" of a spec key, checked by valid(a, b); else TaskSpecError saying `what`."""
    try:
        a, b = (int(v) for v in str(value).lower().split(sep))
        if not valid(a, b):
            raise ValueError
    except ValueError:
        raise TaskSpecError(f"task {text!r}: {what}, got {value!r}") from None
    return a, b


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


def is_image_space(space: gym.Space) -> bool:
    """A uint8 Box of shape (H, W, C) with C 1, 3 or 4, or (H, W): an image."""
    return (isinstance(space, gym.spaces.Box) and space.dtype == np.uint8
            and (len(space.shape) == 2 or (len(space.shape) == 3 and space.shape[2] in (1, 3, 4))))


@dataclass(frozen=True)
class ObservationLayout:
    """How an observation becomes a state: `images` (the keys of the image entries: () for an
    image observation, none for no image) resized to `size` (H, W) and stacked to `channels`,
    then the rest (`rest`: the non-image part's space, or None) flattened."""

    images: tuple | None
    size: tuple
    channels: int
    rest: gym.Space | None

    @property
    def image_shape(self) -> tuple:
        return (*self.size, self.channels) if self.images is not None else ()

    def state_size(self) -> int:
        pixels = int(np.prod(self.image_shape)) if self.images is not None else 0
        return pixels + (gym.spaces.flatdim(self.rest) if self.rest is not None else 0)


def observation_layout(space: gym.Space, spec: TaskSpec) -> ObservationLayout:
    """The layout of observations of `space` (TaskSpecError, one line, if there is none)."""
    if is_image_space(space):
        entries, rest = {(): space}, None
    elif isinstance(space, gym.spaces.Dict) and any(is_image_space(s) for s in space.spaces.values()):
        entries = {k: s for k, s in space.spaces.items() if is_image_space(s)}
        others = {k: s for k, s in space.spaces.items() if k not in entries}
        rest = gym.spaces.Dict(others) if others else None
    else:
        if spec.image is not None:
            raise TaskSpecError(f"task {spec.text!r}: image={spec.image[0]}x{spec.image[1]} but the observation "
                                f"space {space} holds no image (a uint8 Box H x W x C)")
        if spec.encoder is not None:
            raise TaskSpecError(f"task {spec.text!r}: encoder={spec.encoder} but the observation space {space} "
                                f"holds no image (a uint8 Box H x W x C)")
        return ObservationLayout(None, (), 0, space)
    sizes = {tuple(s.shape[:2]) for s in entries.values()}
    if spec.image is None and len(sizes) > 1:
        raise TaskSpecError(f"task {spec.text!r}: the images are of sizes {sorted(sizes)}: give one size to "
                            f"resize them to, e.g. image=64x64")
    size = spec.image or sizes.pop()
    channels = sum(1 if len(s.shape) == 2 else s.shape[2] for s in entries.values())
    images = () if () in entries else tuple(entries)
    return ObservationLayout(images, tuple(size), channels, rest)


def resize_image(image: np.ndarray, size: tuple) -> np.ndarray:
    """An image (H, W[, C]) uint8 resized to `size` (H', W') bilinearly: (H', W', C)."""
    from PIL import Image

    image = np.asarray(image, dtype=np.uint8)
    if image.ndim == 2:
        image = image[..., None]
    if image.shape[:2] == tuple(size):
        return image
    planes = [np.asarray(Image.fromarray(image[..., c]).resize((size[1], size[0]), Image.BILINEAR))
              for c in range(image.shape[2])]
    return np.stack(planes, axis=-1)


def _check_spaces(env: gym.Env, spec: TaskSpec) -> None:
    obs, act = env.observation_space, env.action_space
    try:
        size = observation_layout(obs, spec).state_size()
    except (ValueError, NotImplementedError, TypeError) as exc:
        if isinstance(exc, TaskSpecError):
            raise
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
    """A user's env as a task: flattened float32 states (an image's pixels first, resized:
    `ObservationLayout`), no reward (kept as info["env_reward"]), episodes of at most
    `episode_length` steps (the env's limit or `max_steps`); with `privileged=<key>`,
    info["privileged"] is info[key] as a float32 vector."""

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
        self.spec_ = spec
        self.episode_length = int(limit)
        self._source_space = env.observation_space
        self.layout = observation_layout(self._source_space, spec)
        self.image_shape = self.layout.image_shape
        size = self.layout.state_size()
        self.encoder = None
        if spec.encoder is not None:  # the image's part of the state: its features (a vector task)
            from .frozen_encoder import EncoderError, FrozenEncoder

            try:
                self.encoder = FrozenEncoder(spec.encoder, spec.encoder_weights, self.image_shape, spec.text)
            except EncoderError as exc:
                raise TaskSpecError(str(exc)) from None
            size += self.encoder.size - int(np.prod(self.image_shape))
            self.image_shape = ()
        if spec.xy is not None and max(spec.xy) >= size:
            raise TaskSpecError(f"task {spec.text!r}: xy={spec.xy[0]}/{spec.xy[1]} but the state has "
                                f"{size} dimensions (0..{size - 1})")
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
        self._t = 0

    def _flat(self, obs) -> np.ndarray:
        layout = self.layout
        if layout.images is None:
            return np.asarray(gym.spaces.flatten(self._source_space, obs), dtype=np.float32).reshape(-1)
        images = [obs] if layout.images == () else [obs[k] for k in layout.images]
        image = np.concatenate([resize_image(im, layout.size) for im in images], axis=-1)
        parts = [image.reshape(-1) if self.encoder is None else self._encode(image)]
        if layout.rest is not None:
            parts.append(gym.spaces.flatten(layout.rest, {k: obs[k] for k in layout.rest.spaces}))
        return np.concatenate(parts).astype(np.float32)

    def _encode(self, image: np.ndarray) -> np.ndarray:
        """The frozen encoder's features of one image (its failure: a TaskSpecError, one line)."""
        from .frozen_encoder import EncoderError

        try:
            return self.encoder(image)
        except EncoderError as exc:
            raise TaskSpecError(str(exc)) from None

    def _privileged(self, info: dict) -> dict:
        key = self.spec_.privileged
        if key is None:
            return info
        if key not in info:
            raise TaskSpecError(f"task {self.task!r}: privileged={key} but the env's info has no {key!r} "
                                f"(it has {sorted(info)})")
        value = np.asarray(info[key], dtype=np.float32).reshape(-1)
        if not np.all(np.isfinite(value)):
            raise TaskSpecError(f"task {self.task!r}: the privileged state info[{key!r}] holds NaN or inf")
        return dict(info, privileged=value)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._t = 0
        return self._flat(obs), self._privileged(dict(info, t=0))

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._t += 1
        info = dict(info, t=self._t, env_reward=float(reward))
        return self._flat(obs), 0.0, bool(terminated), bool(truncated), self._privileged(info)


def make_gym_task_env(task: str, render: bool = False) -> GymTaskEnv:
    """The env of task spec `task` (see the module docstring); TaskSpecError if it is unusable.
    `render`: made with render_mode="rgb_array" (`env.render()` returns an RGB frame)."""
    spec = parse_task_spec(task)
    if spec.kind == "lerobot":
        raise TaskSpecError(f"task {task!r} is a recorded LeRobot dataset: it has no environment to run "
                            f"(its episodes can be labelled, modelled and exported; to run episodes or an agent, "
                            f"give the task spec of an environment with the same state)")
    return GymTaskEnv(_construct(spec, render), spec)


def task_encoder(task: str, image_shape: tuple):
    """The `frozen_encoder.FrozenEncoder` a task spec names (`encoder=`, `encoder_weights=`), for images of
    `image_shape` (H, W, C); None for a task without one. EncoderError (one line) if it does not
    load or run. What a robot's observation bridge applies to its cameras' stacked frames."""
    from .frozen_encoder import FrozenEncoder

    if not is_task_spec(task):
        return None
    spec = parse_task_spec(task)
    if spec.encoder is None:
        return None
    return FrozenEncoder(spec.encoder, spec.encoder_weights, image_shape, spec.text)


def encoder_weights_changed(task: str | None, recorded: str | None) -> str | None:
    """How the frozen encoder's weights file of `task` differs from the one whose SHA-256
    `recorded` was taken (a dataset's or a checkpoint's: their states are its features), in words;
    None where nothing was recorded, the spec names no file, the file is not here, or it is the same."""
    now = encoder_weights_sha256(task) if recorded else None
    if now is None or now[1] == recorded:
        return None
    return f"the encoder weights {now[0]} were of SHA-256 {recorded[:12]}..., the file now holds {now[1][:12]}..."


def encoder_weights_sha256(task: str | None) -> tuple[str, str] | None:
    """(path, SHA-256) of the frozen encoder's weights file a task spec names (`encoder_weights=`),
    or None where it names none or the file cannot be read (nothing to compare)."""
    import hashlib
    from pathlib import Path

    if not task or not is_task_spec(task):
        return None
    try:
        weights = parse_task_spec(task).encoder_weights
    except TaskSpecError:
        return None
    if not weights:
        return None
    path = Path(str(weights)).expanduser()
    try:
        return str(path), hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None
