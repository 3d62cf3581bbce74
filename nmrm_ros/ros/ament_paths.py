"""Where the installed ROS 2 packages of this install are, without `source`-ing anything.

ament_index_python finds packages only through `AMENT_PREFIX_PATH`, which a ROS 2 install's
`setup.bash` sets and a plain venv does not. Our two packages know where they were installed:
`<prefix>/lib/pythonX.Y/site-packages/<pkg>/` next to `<prefix>/share/<pkg>/` and the ament index
marker `<prefix>/share/ament_index/resource_index/packages/<pkg>` (pip into a venv and colcon
both lay them out so). `ensure_ament_prefix_path()` adds those prefixes to `AMENT_PREFIX_PATH`
(in this process, inherited by the nodes it starts) when they are missing from it.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

PACKAGES = ("nmrm_ros", "nmrm_msgs")


def installed_prefix(package: str) -> Path | None:
    """The install prefix of importable `package` if it carries its ament index marker, else None."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.origin:
        return None
    parents = Path(spec.origin).resolve().parents
    if len(parents) < 5:
        return None
    prefix = parents[4]  # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
    return prefix if marker.is_file() else None


def ensure_ament_prefix_path() -> list:
    """Append the install prefixes of our packages to AMENT_PREFIX_PATH where missing; returns
    the prefixes added (empty if the environment already had them)."""
    current = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    known = {os.path.realpath(p) for p in current}
    added = []
    for package in PACKAGES:
        prefix = installed_prefix(package)
        if prefix is not None and os.path.realpath(prefix) not in known:
            known.add(os.path.realpath(prefix))
            added.append(str(prefix))
    if added:
        os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join(current + added)
    return added


def share_dir(package: str) -> Path | None:
    """`<prefix>/share/<package>` from AMENT_PREFIX_PATH or the package's own install, else None."""
    ensure_ament_prefix_path()
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        d = Path(prefix) / "share" / package
        if prefix and d.is_dir():
            return d
    return None


def require_share_dir(package: str) -> Path:
    """`share_dir(package)`, or a FileNotFoundError saying how to install it."""
    share = share_dir(package)
    if share is None:
        raise FileNotFoundError(f"share/{package} not found: install the package (bash scripts/setup_env.sh, "
                                f"or colcon build and source install/setup.bash)")
    return share


def node_command(name: str, **params) -> list:
    """The command line of node executable `name` as `ros2 run nmrm_ros NAME` runs it
    (`<prefix>/lib/nmrm_ros/NAME`), with `params` as `--ros-args -p k:=v` (bools lower-case)."""
    from ament_index_python.packages import get_package_prefix

    ensure_ament_prefix_path()
    cmd = [str(Path(get_package_prefix("nmrm_ros")) / "lib" / "nmrm_ros" / name)]
    if params:
        cmd.append("--ros-args")
        for k, v in params.items():
            cmd += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
    return cmd
