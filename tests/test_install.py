"""The install is what a ROS 2 user expects: ament index entries and runnable lib/ executables."""

import os
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

#: every executable setup.py declares; a missing one must fail, not just give fewer cases
EXPECTED_EXECUTABLES = ("action_bridge", "agent", "env_sim", "fake_robot", "foxglove_server", "labeller_oracle",
                        "labeller_web",
                        "nmrm", "observation_bridge", "recorder", "replay", "reward_model", "trainer", "visualizer")


def test_ament_index_finds_packages():
    for pkg in ("nmrm_ros", "nmrm_msgs"):
        prefix = Path(get_package_prefix(pkg))
        assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / pkg).is_file()
    share = Path(get_package_share_directory("nmrm_ros"))
    assert (share / "package.xml").read_text().count("<name>nmrm_ros</name>") == 1


def _lib_executables():
    lib = Path(get_package_prefix("nmrm_ros")) / "lib" / "nmrm_ros"
    return sorted(p for p in lib.iterdir() if p.is_file() and os.access(p, os.X_OK))


def test_expected_executables_installed():
    names = {p.name for p in _lib_executables()}
    assert names == set(EXPECTED_EXECUTABLES), names


@pytest.mark.parametrize("name", EXPECTED_EXECUTABLES)
def test_executable_help(name):
    """`ros2 run nmrm_ros <exe> --help` runs exactly this file."""
    exe = Path(get_package_prefix("nmrm_ros")) / "lib" / "nmrm_ros" / name
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "usage" in out.stdout.lower()


def test_cli_and_nodes_need_no_sourcing(ros_domain, tmp_path):
    """With none of scripts/ros_env.sh's variables (no AMENT_PREFIX_PATH, venv not on PATH), the
    CLI launches a graph that records a bag and reads it back: the packages find their own
    install prefix and message definitions."""
    prefix = Path(get_package_prefix("nmrm_ros"))
    env = {"HOME": str(tmp_path), "PATH": "/usr/bin:/bin", "ROS_DOMAIN_ID": os.environ["ROS_DOMAIN_ID"],
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    nmrm = str(prefix / "bin" / "nmrm")
    launch_file = Path(__file__).resolve().parents[1] / "launch_scripts" / "collect.launch.yaml"
    out = subprocess.run([nmrm, "launch", str(launch_file), "episodes:=2", f"out:={tmp_path / 'bag'}"],
                         capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert out.returncode == 0 and "all 4 node(s) exited cleanly" in out.stdout, out.stdout + out.stderr
    info = subprocess.run([nmrm, "bag", "info", str(tmp_path / "bag")], capture_output=True, text=True,
                          timeout=60, env=env, cwd=tmp_path)
    assert info.returncode == 0 and "2 episodes in the bags, 2 used" in info.stdout, info.stdout + info.stderr
