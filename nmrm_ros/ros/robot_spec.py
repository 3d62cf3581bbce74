"""A robot described in one YAML file: which standard topics make its state, how an action becomes
a twist, and when an episode ends (no node, no spin; read by observation_bridge and action_bridge).

    observation:
      rate: 10.0                 # Hz: one observation per tick, of the latest value of every input
      stale_after: 0.5           # s: a tick with an input older than this (or never seen) is skipped, counted
      inputs:
        - {topic: /odom, type: nav_msgs/msg/Odometry, qos: sensor_data,
           fields: [pose.pose.position.x, pose.pose.position.y, "yaw(pose.pose.orientation)"]}
        - {topic: /scan, type: sensor_msgs/msg/LaserScan, qos: sensor_data, fields: [ranges], downsample: 8}
        - {topic: /camera/image_raw/compressed, type: sensor_msgs/msg/CompressedImage, qos: sensor_data,
           image: 64x64}         # a camera: its frame resized to 64x64 RGB (channels: 1 for grey)
        - {topic: /mocap/pose, type: geometry_msgs/msg/PoseStamped, fields: [pose.position.x,
           pose.position.y], privileged: true}   # for the oracle and the plots only
    episode:
      max_steps: 200             # truncated at this step
      box: {dims: [0, 1], low: [-2.0, -2.0], high: [2.0, 2.0]}   # terminated when a state leaves it
      reset_service: /reset      # std_srvs/srv/Empty called between episodes ('' or absent: none)
    action:
      topic: /cmd_vel
      stamped: false             # geometry_msgs/TwistStamped instead of Twist
      rate: 10.0                 # Hz: the current command is re-sent (robots expect a stream)
      timeout: 0.5               # s without an action: a zero twist (the safe stop)
      discrete:                  # action index -> twist fields
        0: {linear.x: 0.2}
        1: {angular.z: 1.0}
      # or continuous: {fields: [linear.x, angular.z], low: [-0.2, -1.0], high: [0.2, 1.0]}

The state is the cameras' pixels first (`sensor_msgs/Image` in any common encoding, or
`CompressedImage`; `image: HxW`, all cameras of one size, stacked along the channels in order:
`nmrm_ros.ros.image_messages`), then the other inputs' fields in order: the task's state (the
bridge's `task` parameter; with cameras, a task whose `image_shape` is H x W x the channels).
Inputs marked `privileged: true` are not in the state: their fields are the observation's
privileged state (what an oracle judges with; a model or an agent never sees it). Every mistake is
a ValueError naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import yaml

from .field_paths import compile_fields
from .image_messages import IMAGE_TYPES, image_reader, is_image_type

TWIST_FIELDS = tuple(f"{part}.{axis}" for part in ("linear", "angular") for axis in "xyz")
QOS_NAMES = ("sensor_data", "reliable")


@dataclass
class InputSpec:
    topic: str
    type_name: str
    fields: list
    qos: str = "reliable"
    downsample: int | None = None
    read: Callable | None = None  # msg -> list of floats, or (H, W, C) uint8 pixels of a camera
    image: tuple | None = None    # a camera: (H, W) its frames are resized to
    channels: int = 0             # a camera: 3 (RGB) or 1 (grey)
    privileged: bool = False      # its fields go to the privileged state, not the state


@dataclass
class RobotSpec:
    inputs: list
    rate: float = 10.0
    stale_after: float = 0.5
    max_steps: int = 0          # 0: no limit (episodes end by service or the box)
    box_dims: list = field(default_factory=list)
    box_low: list = field(default_factory=list)
    box_high: list = field(default_factory=list)
    reset_service: str = ""
    action_topic: str = "/cmd_vel"
    stamped: bool = False
    action_rate: float = 10.0
    action_timeout: float = 0.5
    discrete: dict = field(default_factory=dict)       # index -> {twist field: value}
    continuous_fields: list = field(default_factory=list)
    continuous_low: list = field(default_factory=list)
    continuous_high: list = field(default_factory=list)

    @property
    def cameras(self) -> list:
        """The camera inputs, in order (their pixels lead the state)."""
        return [i for i in self.inputs if i.image is not None]

    @property
    def image_shape(self) -> tuple:
        """(H, W, C) of the state's image (the cameras stacked along C), () without a camera."""
        cams = self.cameras
        return (*cams[0].image, sum(c.channels for c in cams)) if cams else ()

    def left_box(self, state) -> bool:
        """True if `state` is outside the episode box (no box: never)."""
        return any(not lo <= state[d] <= hi for d, lo, hi in zip(self.box_dims, self.box_low, self.box_high))

    def twist(self, action) -> dict:
        """{twist field: value} for an AgentAction's values (discrete: the index; continuous:
        the vector, clipped to [low, high]); ValueError for an unknown index or a wrong size."""
        values = [float(a) for a in action]
        if self.discrete:
            if len(values) != 1 or values[0] != int(values[0]) or int(values[0]) not in self.discrete:
                raise ValueError(f"action {values} is not one of {sorted(self.discrete)}")
            return dict(self.discrete[int(values[0])])
        if len(values) != len(self.continuous_fields):
            raise ValueError(f"action has {len(values)} values, the spec maps {len(self.continuous_fields)}")
        return {f: min(max(v, lo), hi) for f, v, lo, hi in
                zip(self.continuous_fields, values, self.continuous_low, self.continuous_high)}


def _number(table: dict, key: str, default, where: str, positive: bool = False, whole: bool = False):
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}.{key} must be a number, got {value!r}")
    if positive and not value > 0:
        raise ValueError(f"{where}.{key} must be > 0, got {value!r}")
    if whole and (value != int(value) or value < 0):
        raise ValueError(f"{where}.{key} must be a whole number >= 0, got {value!r}")
    return int(value) if whole else float(value)


def _table(parent: dict, key: str, where: str, required: bool = True) -> dict:
    value = parent.get(key, None if required else {})
    if not isinstance(value, dict):
        raise ValueError(f"{where}{key} must be a mapping" + ("" if value is not None else " (missing)"))
    return value


def parse_robot_spec(text: str, source: str = "robot spec") -> RobotSpec:
    """A RobotSpec from YAML text; ValueError (naming the key) for anything wrong."""
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{source} is not YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{source} must be a mapping with observation:, episode: and action:")
    unknown = set(raw) - {"observation", "episode", "action"}
    if unknown:
        raise ValueError(f"{source}: unknown section(s) {sorted(unknown)}")
    obs = _table(raw, "observation", "")
    inputs = []
    if not isinstance(obs.get("inputs"), list) or not obs["inputs"]:
        raise ValueError("observation.inputs must be a non-empty list")
    for i, item in enumerate(obs["inputs"]):
        where = f"observation.inputs[{i}]"
        if not isinstance(item, dict):
            raise ValueError(f"{where} must be a mapping")
        for key in ("topic", "type"):
            if key not in item:
                raise ValueError(f"{where}.{key} is missing")
        qos = item.get("qos", "reliable")
        if qos not in QOS_NAMES:
            raise ValueError(f"{where}.qos must be one of {', '.join(QOS_NAMES)}, got {qos!r}")
        privileged = item.get("privileged", False)
        if not isinstance(privileged, bool):
            raise ValueError(f"{where}.privileged must be true or false, got {privileged!r}")
        if is_image_type(str(item["type"])):
            inputs.append(_camera(item, where, qos, privileged))
            continue
        if "fields" not in item:
            raise ValueError(f"{where}.fields is missing")
        if not isinstance(item["fields"], list):
            raise ValueError(f"{where}.fields must be a list")
        unknown = set(item) - {"topic", "type", "fields", "qos", "downsample", "privileged"}
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {sorted(unknown)} (image: is for camera types, "
                             f"{', '.join(IMAGE_TYPES)})")
        spec = InputSpec(str(item["topic"]), str(item["type"]), list(item["fields"]), qos, item.get("downsample"),
                         privileged=privileged)
        spec.read = compile_fields(spec.type_name, spec.fields, spec.downsample, where=f"{where} ({spec.topic})")
        inputs.append(spec)
    sizes = {i.image for i in inputs if i.image is not None}
    if len(sizes) > 1:
        raise ValueError(f"observation.inputs: the cameras must share one image size, got "
                         f"{', '.join(f'{h}x{w}' for h, w in sorted(sizes))}")
    if all(i.privileged for i in inputs):
        raise ValueError("observation.inputs: every input is privileged: the state would be empty")
    ep = _table(raw, "episode", "", required=False)
    box = _table(ep, "box", "episode.", required=False)
    dims, low, high = (list(box.get(k, [])) for k in ("dims", "low", "high"))
    if not len(dims) == len(low) == len(high):
        raise ValueError("episode.box: dims, low and high must have one entry each per dimension")
    act = _table(raw, "action", "", required=False)
    discrete, cont = act.get("discrete", {}), act.get("continuous")
    if discrete and cont:
        raise ValueError("action: give discrete or continuous, not both")
    table = {}
    for index, fields in (discrete or {}).items():
        if isinstance(index, bool) or not isinstance(index, int) or not isinstance(fields, dict):
            raise ValueError(f"action.discrete: {index!r} -> {fields!r} must be an action index -> {{twist field: value}}")
        bad = set(fields) - set(TWIST_FIELDS)
        if bad:
            raise ValueError(f"action.discrete[{index}]: {sorted(bad)} are not twist fields ({', '.join(TWIST_FIELDS)})")
        table[index] = {k: float(v) for k, v in fields.items()}
    cont_fields, cont_low, cont_high = [], [], []
    if cont is not None:
        if not isinstance(cont, dict):
            raise ValueError("action.continuous must be a mapping of fields, low, high")
        cont_fields, cont_low, cont_high = (list(cont.get(k, [])) for k in ("fields", "low", "high"))
        if not cont_fields or not len(cont_fields) == len(cont_low) == len(cont_high):
            raise ValueError("action.continuous: fields, low and high must have one entry each per action value")
        bad = set(cont_fields) - set(TWIST_FIELDS)
        if bad:
            raise ValueError(f"action.continuous: {sorted(bad)} are not twist fields")
        if any(lo > hi for lo, hi in zip(cont_low, cont_high)):
            raise ValueError("action.continuous: every low must be <= its high")
    return RobotSpec(
        inputs=inputs, rate=_number(obs, "rate", 10.0, "observation", positive=True),
        stale_after=_number(obs, "stale_after", 0.5, "observation", positive=True),
        max_steps=_number(ep, "max_steps", 0, "episode", whole=True), box_dims=[int(d) for d in dims],
        box_low=[float(x) for x in low], box_high=[float(x) for x in high],
        reset_service=str(ep.get("reset_service", "") or ""), action_topic=str(act.get("topic", "/cmd_vel")),
        stamped=bool(act.get("stamped", False)), action_rate=_number(act, "rate", 10.0, "action", positive=True),
        action_timeout=_number(act, "timeout", 0.5, "action", positive=True), discrete=table,
        continuous_fields=cont_fields, continuous_low=[float(x) for x in cont_low],
        continuous_high=[float(x) for x in cont_high])


def _camera(item: dict, where: str, qos: str, privileged: bool) -> InputSpec:
    """The InputSpec of a camera input (`image: HxW`, optional `channels: 3 | 1`)."""
    unknown = set(item) - {"topic", "type", "qos", "image", "channels", "privileged"}
    if unknown:
        raise ValueError(f"{where}: a camera input takes topic, type, qos, image and channels, not {sorted(unknown)}")
    if privileged:
        raise ValueError(f"{where}: a camera cannot be privileged (the privileged state is numbers)")
    try:
        h, w = (int(v) for v in str(item.get("image", "")).lower().split("x"))
        if h < 1 or w < 1:
            raise ValueError
    except ValueError:
        raise ValueError(f"{where}.image must be the size HxW its frames are resized to, e.g. 64x64, "
                         f"got {item.get('image')!r}") from None
    channels = item.get("channels", 3)
    if channels not in (1, 3) or isinstance(channels, bool):
        raise ValueError(f"{where}.channels must be 3 (RGB) or 1 (grey), got {channels!r}")
    spec = InputSpec(str(item["topic"]), str(item["type"]), [], qos, image=(h, w), channels=int(channels))
    spec.read = image_reader(spec.type_name, spec.image, spec.channels)
    return spec


def load_robot_spec(path: str | Path) -> RobotSpec:
    """The RobotSpec of a YAML file; ValueError if it is missing or wrong."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no robot spec file {path}")
    return parse_robot_spec(path.read_text(), source=str(path))
