"""The ros2msg schema text of any installed message type, dependencies included.

A viewer that decodes CDR without our packages (Foxglove, the `mcap` CLI, rosbags) needs a type's
.msg text followed by each type it uses, depth first, each after a line of 80 '=' and a
`MSG: pkg/Type` line (the rosbag2 / MCAP ros2msg convention). The .msg files are read from the
installed share directories (ament index: `<prefix>/share/<pkg>/msg/<Type>.msg`).
"""

from __future__ import annotations

import re
from functools import lru_cache

from .ament_paths import share_dir

SEPARATOR = "=" * 80
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
               "uint32", "int64", "uint64", "string", "wstring"}


@lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    """The .msg text of `type_name` ('pkg/msg/Type' or 'pkg/Type'); ValueError if not installed."""
    pkg, _, name = type_name.replace("/msg/", "/").partition("/")
    share = share_dir(pkg)
    path = share / "msg" / f"{name}.msg" if share is not None else None
    if path is None or not path.is_file():
        raise ValueError(f"no installed message definition for {type_name!r}")
    return path.read_text()


def _used_types(text: str, pkg: str) -> list:
    """The complex types the fields of a .msg text use, as 'pkg/Type', in order of appearance."""
    used = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if len(tokens) < 2 or "=" in " ".join(tokens[1:]):  # blank, comment or a constant
            continue
        base = re.sub(r"(<=\d+)?(\[[^\]]*\])?$", "", tokens[0])
        if base in _PRIMITIVES:
            continue
        full = "std_msgs/Header" if base == "Header" else base if "/" in base else f"{pkg}/{base}"
        full = full.replace("/msg/", "/")
        if full not in used:
            used.append(full)
    return used


@lru_cache(maxsize=None)
def ros2msg_schema(type_name: str) -> str:
    """`type_name`'s .msg text, then every type it uses (depth first, each once)."""
    root = type_name.replace("/msg/", "/")
    parts = [msg_text(root).rstrip()]
    seen = {root}
    stack = list(reversed(_used_types(parts[0], root.partition("/")[0])))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.add(dep)
        text = msg_text(dep).rstrip()
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{text}")
        stack.extend(reversed([t for t in _used_types(text, dep.partition("/")[0]) if t not in seen]))
    return "\n".join(parts) + "\n"
