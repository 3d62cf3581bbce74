"""Reading state dimensions out of standard ROS messages by field paths (no node, no spin).

A field path names numbers in a message:
  pose.pose.position.x         one number (attributes, dotted)
  ranges[3]  data[0]           one element of an array
  position[wheel_left]         JointState: the element of `position` at the index of that name in `name`
  yaw(pose.pose.orientation)   the heading (rad) of a quaternion
  ranges                       the whole array; with `downsample: k`, k sectors, each its minimum
                               (LaserScan: inf / NaN read as range_max, so a sector with nothing
                               in it is "far", not missing)
`compile_fields(type_name, paths, downsample)` checks every path against a default message of the
type (attribute names; indices only when a message arrives) and returns a function msg -> list of
floats; a path that does not fit the type is a ValueError naming it, and so is a message whose
array is too short, whose joint name is missing or whose number is not finite.
"""

from __future__ import annotations

import importlib
import math
import re
from typing import Callable

import numpy as np

_INDEXED = re.compile(r"^(?P<path>[A-Za-z_][\w.]*)\[(?P<index>[^\]]+)\]$")
_YAW = re.compile(r"^yaw\((?P<path>[A-Za-z_][\w.]*)\)$")
_PLAIN = re.compile(r"^[A-Za-z_][\w.]*$")


def message_class(type_name: str):
    """'nav_msgs/msg/Odometry' (or 'nav_msgs/Odometry') -> the message class; ValueError if unknown."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or parts[1] != "msg" or not all(parts):
        raise ValueError(f"message type {type_name!r} is not pkg/msg/Type")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f"unknown message type {type_name!r} (is its package installed?)") from None


def _get(msg, path: str, where: str):
    value = msg
    for name in path.split("."):
        if not hasattr(value, name) or name.startswith("_"):
            raise ValueError(f"{where}: {type(value).__name__} has no field {name!r}")
        value = getattr(value, name)
    return value


def _number(value, where: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: not a number ({type(value).__name__})") from None
    if not math.isfinite(x):
        raise ValueError(f"{where}: not finite ({x})")
    return x


def yaw(q) -> float:
    """The heading (rotation about z, rad) of a quaternion with fields x, y, z, w."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def sectors(values, k: int, fill: float) -> list:
    """k sector minima of an array (non-finite values read as `fill`)."""
    a = np.asarray(values, dtype=np.float64)
    if len(a) < k:
        raise ValueError(f"{len(a)} values cannot make {k} sectors")
    a = np.where(np.isfinite(a), a, fill)
    return [float(part.min()) for part in np.array_split(a, k)]


def _one(path: str, downsample: int | None, where: str) -> Callable:
    """msg -> list of floats for one field path."""
    m = _YAW.match(path)
    if m:
        inner = m["path"]
        return lambda msg: [_number(yaw(_get(msg, inner, where)), where)]
    m = _INDEXED.match(path)
    if m:
        array_path, index = m["path"], m["index"].strip()
        if re.fullmatch(r"\d+", index):
            i = int(index)

            def element(msg):
                values = _get(msg, array_path, where)
                if i >= len(values):
                    raise ValueError(f"{where}: {array_path} has {len(values)} values, no [{i}]")
                return [_number(values[i], where)]
            return element

        def named(msg):  # JointState: position[name] -> position[names.index(name)]
            names = list(_get(msg, "name", where))
            if index not in names:
                raise ValueError(f"{where}: no joint {index!r} (joints: {names})")
            values = _get(msg, array_path, where)
            j = names.index(index)
            if j >= len(values):
                raise ValueError(f"{where}: {array_path} has {len(values)} values, no [{j}] for {index!r}")
            return [_number(values[j], where)]
        return named
    if not _PLAIN.match(path):
        raise ValueError(f"{where}: cannot read field path {path!r} (a.b.c, a[3], position[joint], yaw(a.b))")

    def whole(msg):
        value = _get(msg, path, where)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return [_number(value, where)]
        try:
            values = list(value)
        except TypeError:
            raise ValueError(f"{where}: a {type(value).__name__}, not a number or an array") from None
        if downsample:
            fill = float(getattr(msg, "range_max", float("inf")))
            return sectors(values, downsample, fill if math.isfinite(fill) else 0.0)
        return [_number(v, where) for v in values]
    return whole


def compile_fields(type_name: str, paths: list, downsample: int | None = None, where: str = "") -> Callable:
    """msg -> list of floats: the fields `paths` of a `type_name` message in order (see the module
    docstring). ValueError at once for a path the type does not have."""
    cls = message_class(type_name)
    if not paths:
        raise ValueError(f"{where or type_name}: no fields given")
    if downsample is not None and (isinstance(downsample, bool) or not isinstance(downsample, int) or downsample < 1):
        raise ValueError(f"{where or type_name}: downsample must be a whole number >= 1, got {downsample!r}")
    readers = []
    template = cls()
    for path in paths:
        if not isinstance(path, str):
            raise ValueError(f"{where or type_name}: a field path must be a string, got {path!r}")
        label = f"{where + ' ' if where else ''}{path}"
        reader = _one(path.strip(), downsample, label)
        inner = (_YAW.match(path) or _INDEXED.match(path))
        _get(template, inner["path"] if inner else path.strip(), label)  # the attributes exist
        readers.append(reader)
    return lambda msg: [x for r in readers for x in r(msg)]
