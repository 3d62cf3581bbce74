"""Message definitions (ros2msg schema text) and type hashes of the types our bags carry.

The schema of a message is its .msg text followed by the definitions of the types it uses, each
after a line of 80 '=' and a `MSG: pkg/Type` line (the rosbag2 / MCAP ros2msg convention), so that
any reader (rosbag2, Foxglove, the `mcap` and `rosbags` libraries) can decode a bag without our
packages installed. The nmrm_msgs definitions are read from the installed share directory (ament
index) or, without ROS, from the source tree's msg_defs/.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

from ..ros.ament_paths import share_dir as _share_dir

NMRM_TYPES = ("EnvObservation", "AgentAction", "RewardStep", "TrajectoryReturn", "OracleStep",
              "TrajectoryPreference")
#: standard ROS 2 types our graph publishes too: their .msg text (without the Header's definition)
STANDARD_TYPES = {"sensor_msgs/msg/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n"}

#: an image task's pixels (`tasks.image_states`), beside the observation topic of its graph
IMAGE_TOPIC = "/nmrm/observation_image"
#: Default topic -> type of the nmrm graph (same names as nmrm_ros.ros.topics, absolute).
TOPIC_TYPES = {
    "/nmrm/observation": "nmrm_msgs/msg/EnvObservation",
    "/nmrm/action": "nmrm_msgs/msg/AgentAction",
    "/nmrm/reward_step": "nmrm_msgs/msg/RewardStep",
    "/nmrm/trajectory_return": "nmrm_msgs/msg/TrajectoryReturn",
    "/nmrm/oracle_step": "nmrm_msgs/msg/OracleStep",
    "/nmrm/trajectory_preference": "nmrm_msgs/msg/TrajectoryPreference",
    "/nmrm/frame": "sensor_msgs/msg/CompressedImage",  # env_sim render:=true (nmrm_ros.tasks.frames)
    IMAGE_TOPIC: "sensor_msgs/msg/CompressedImage",
}


def with_observation_images(topics: list, available=None) -> list:
    """`topics` and, after each observation or reward-step topic, the observation-image topic of
    its graph (an image task's pixels travel there: its states are incomplete without them), if
    not named already and, when `available` is given, in it: '/robot1/nmrm/observation' brings
    '/robot1/nmrm/observation_image'."""
    out = list(topics)
    for t in topics:
        for step in ("/nmrm/observation", "/nmrm/reward_step"):
            image = t[: -len(step)] + IMAGE_TOPIC
            if t.endswith(step) and image not in out and (available is None or image in available):
                out.append(image)
    return out


def split_topic(name: str) -> tuple[str, str]:
    """A fully qualified nmrm topic -> (source namespace, type name):
    '/robot1/nmrm/observation' -> ('/robot1', 'nmrm_msgs/msg/EnvObservation'); '/nmrm/action' ->
    ('', 'nmrm_msgs/msg/AgentAction'). The namespace is the source id of the graph that published
    it (episodes of two robots are told apart by it). ValueError for any other topic."""
    for base, type_name in TOPIC_TYPES.items():
        if name == base or (name.endswith(base) and name.startswith("/")):
            return name[: len(name) - len(base)], type_name
    raise ValueError(f"not an nmrm topic: {name!r} (known: {list(TOPIC_TYPES)}, in any namespace)")


_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_SEPARATOR = "=" * 80


def _nmrm_msg_dir() -> Path:
    """share/nmrm_msgs/msg of the installed messages, else msg_defs/msg of a source checkout."""
    share = _share_dir("nmrm_msgs")
    if share is not None and (share / "msg").is_dir():
        return share / "msg"
    source = Path(__file__).resolve().parents[2] / "msg_defs" / "msg"
    if source.is_dir():
        return source
    raise FileNotFoundError("nmrm_msgs message definitions not found: install the nmrm_msgs package "
                            "(bash scripts/setup_env.sh, or colcon build) or set AMENT_PREFIX_PATH")


def short_name(type_name: str) -> str:
    """'nmrm_msgs/msg/EnvObservation' -> 'EnvObservation' (and check it is one our bags carry)."""
    pkg, _, name = type_name.partition("/msg/")
    if type_name not in STANDARD_TYPES and (pkg != "nmrm_msgs" or name not in NMRM_TYPES):
        raise ValueError(f"not a type of our bags: {type_name!r}")
    return name


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """The ros2msg schema text of a type our bags carry, dependencies included."""
    text = STANDARD_TYPES.get(type_name) or (_nmrm_msg_dir() / f"{short_name(type_name)}.msg").read_text()
    return (f"{text.rstrip()}\n{_SEPARATOR}\nMSG: std_msgs/Header\n{_HEADER}"
            f"{_SEPARATOR}\nMSG: builtin_interfaces/Time\n{_TIME}")


@lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The RIHS01 type hash from the installed type description, or '' without ROS."""
    share = _share_dir(type_name.partition("/")[0])
    if share is None:
        return ""
    path = share / "msg" / f"{short_name(type_name)}.json"
    try:
        data = json.loads(path.read_text())
        return data["type_hashes"][0]["hash_string"]
    except (OSError, KeyError, IndexError, ValueError):
        return ""
