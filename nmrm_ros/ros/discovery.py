"""Fast DDS discovery settings of our processes: participants re-announce every 0.25 s.

Fast DDS discovery is one-sided until the other participant announces itself again (every 3 s by
default): a process started before or after a graph's nodes (a recorder, a viewer, a labelling
page) matched some of their publishers only ~3.5 s later and lost what they published meanwhile,
since our topics are volatile. `use_discovery_profile()` points FASTRTPS_DEFAULT_PROFILES_FILE at
config/fastdds_discovery.xml (announcements every 0.25 s) unless the user chose a profile file
(that variable, FASTDDS_DEFAULT_PROFILES_FILE, or DEFAULT_FASTRTPS_PROFILES.xml in the working
directory). Call it before rclpy.init(); processes started afterwards inherit it. Plain Python.
"""

from __future__ import annotations

import os
from pathlib import Path

PROFILE_NAME = "fastdds_discovery.xml"
_USER_SETTINGS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def discovery_profile() -> Path | None:
    """config/fastdds_discovery.xml of the source tree, else of the installed share directory."""
    source = Path(__file__).resolve().parents[2] / "config" / PROFILE_NAME
    if source.is_file():
        return source
    from .ament_paths import share_dir

    share = share_dir("nmrm_ros")
    installed = share / "config" / PROFILE_NAME if share is not None else None
    return installed if installed is not None and installed.is_file() else None


def use_discovery_profile() -> Path | None:
    """Set FASTRTPS_DEFAULT_PROFILES_FILE to our profile unless the user chose one; returns the
    profile in effect if it is ours, else None."""
    if any(os.environ.get(v) for v in _USER_SETTINGS) or Path("DEFAULT_FASTRTPS_PROFILES.xml").is_file():
        return None
    profile = discovery_profile()
    if profile is not None:
        os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    return profile
