"""Build script of the nmrm_ros ament_python package.

Two ways to install, one layout for `ros2 run nmrm_ros <exe>`:
- colcon (on a ROS 2 install) runs `setup.py develop/install`; setup.cfg sends the console scripts
  to `lib/nmrm_ros/`, where `ros2 run` looks.
- pip (our venv, see scripts/setup_env.sh) builds a wheel and ignores setup.cfg's script dirs, so
  the console scripts land in `bin/`. For that case we also install small shims into
  `lib/nmrm_ros/` that exec the `bin/` script of the same name.
"""

import os
import sys
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "nmrm_ros"

# Executable name -> entry point. Every executable also gets a `lib/nmrm_ros/` shim under pip.
EXECUTABLES = {
    "nmrm": "nmrm_ros.cli:main",
    "env_sim": "nmrm_ros.nodes.env_sim_node:main",
    "labeller_oracle": "nmrm_ros.nodes.labeller_oracle_node:main",
    "labeller_web": "nmrm_ros.nodes.labeller_web_node:main",
    "reward_model": "nmrm_ros.nodes.reward_model_node:main",
    "agent": "nmrm_ros.nodes.agent_node:main",
    "recorder": "nmrm_ros.nodes.recorder_node:main",
    "replay": "nmrm_ros.nodes.replay_node:main",
    "trainer": "nmrm_ros.nodes.trainer_node:main",
    "observation_bridge": "nmrm_ros.nodes.observation_bridge_node:main",
    "action_bridge": "nmrm_ros.nodes.action_bridge_node:main",
    "fake_robot": "nmrm_ros.nodes.fake_robot_node:main",
    "visualizer": "nmrm_ros.nodes.visualizer_node:main",
    "foxglove_server": "nmrm_ros.nodes.foxglove_server_node:main",
}

SHIM = """#!/bin/sh
# nmrm_ros: `ros2 run` looks in lib/nmrm_ros/; pip puts console scripts in bin/. Run that one.
exec "$(dirname "$0")/../../bin/$(basename "$0")" "$@"
"""


def _building_wheel() -> bool:
    """True under a PEP 517 build (pip), false under colcon's setup.py develop/install."""
    return any(arg in ("bdist_wheel", "editable_wheel") for arg in sys.argv)


def _shim_files() -> list:
    shim_dir = os.path.join("build", "ros_shims")
    os.makedirs(shim_dir, exist_ok=True)
    paths = []
    for name in EXECUTABLES:
        path = os.path.join(shim_dir, name)
        with open(path, "w") as f:
            f.write(SHIM)
        os.chmod(path, 0o755)
        paths.append(path)
    return paths


data_files = [
    ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
    (f"share/{PACKAGE}", ["package.xml"]),
    (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.xml"))),
    (f"share/{PACKAGE}/config/robots", sorted(glob("config/robots/*.yaml"))),
    (f"share/{PACKAGE}/config/foxglove", sorted(glob("config/foxglove/*.json"))),
    (f"share/{PACKAGE}/launch_scripts", sorted(glob("launch_scripts/*"))),
]
if _building_wheel():
    data_files.append((f"lib/{PACKAGE}", _shim_files()))

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=data_files,
    package_data={f"{PACKAGE}.labelling": ["static/*"]},
    zip_safe=True,
    maintainer="nmrm_ros developers",
    maintainer_email="nmrm-dev@example.com",
    description="Non-Markovian reward modelling with MIL as a ROS 2 node graph",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()],
    },
)
