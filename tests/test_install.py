"""The install is what a ROS 2 user expects: ament index entries and runnable lib/ executables."""

import os
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

#: every executable setup.py declares; a missing one must fail, not just give fewer cases
EXPECTED_EXECUTABLES = ("agent", "env_sim", "labeller_oracle", "nmrm", "recorder", "replay", "reward_model")


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
