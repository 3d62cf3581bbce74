"""Shared fixtures: each ROS test gets a DDS domain of its own, and subprocess helpers."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import pytest


def _worker() -> tuple[int, int]:
    """(this pytest-xdist worker's index, the number of workers); (0, 1) in a run without workers."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    return int(name[2:]), max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))


# In a parallel run each worker, and every process it starts, gets its share of the cores for
# torch's (OpenMP's) threads: two workers each training with every core's thread ran 4 spinning
# threads on 2 cores, and a toy training test that takes 47 s took over 300 s (its timeout).
# Set before torch is first imported, which reads it.
if _worker()[1] > 1:
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // _worker()[1])))

from nmrm_ros.ros.discovery import use_discovery_profile  # noqa: E402

use_discovery_profile()  # the in-process rclpy nodes and the ros2 CLI discover as our nodes do

REPO = Path(__file__).resolve().parents[1]
_domain_counter = itertools.count()
_BASE_DOMAIN = int(os.environ.get("ROS_DOMAIN_ID", "0"))  # the run's (scripts/ros_env.sh: random per run)


def _domains() -> range:
    """The DDS domains this process's tests may use: 1..100 (ROS 2's safe range on Linux: higher
    domains' ports reach the ephemeral range), split evenly between the workers of a parallel run
    (`scripts/test.sh` runs two), so that two tests running at once never share one."""
    index, count = _worker()
    span = 100 // count
    return range(1 + index * span, 1 + (index + 1) * span)


@pytest.fixture(autouse=True)
def _worker_domain(monkeypatch) -> None:
    """In a parallel run, a test that does not ask for `ros_domain` still talks in its worker's own
    domains (one chosen by the run's random base, as a run without workers uses the base itself, so
    that two runs on one machine seldom meet), never in another worker's."""
    if _worker()[1] > 1:
        domains = _domains()
        monkeypatch.setenv("ROS_DOMAIN_ID", str(domains[_BASE_DOMAIN % len(domains)]))


@pytest.fixture
def ros_domain(monkeypatch) -> int:
    """A ROS_DOMAIN_ID for this test alone (derived from the run's base id and the pid, within the
    worker's own domains).

    Set in os.environ, so the in-process rclpy context and every subprocess started after it use
    it. Domains 0..232 are valid for Fast DDS; we stay in 1..100 (`_domains`).
    """
    domains = _domains()
    domain = domains[(_BASE_DOMAIN * 7 + os.getpid() + next(_domain_counter) * 13) % len(domains)]
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST"))
    return domain


def run_python(script: Path | str, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run a helper script with this interpreter in its own process; capture text output."""
    return subprocess.run(
        [sys.executable, str(script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=os.environ.copy(),
    )


@pytest.fixture(scope="session")
def small_key_checkpoint(tmp_path_factory):
    """A CSC model trained for 2 epochs on 200 screened Key episodes (data seed 0, weight seed 0)."""
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.pipeline import fit

    ds = generate_screened("key", 200, seed=0)
    path = tmp_path_factory.mktemp("ckpt") / "key_csc"
    return fit(ds, "csc_lstm", load_train_config("key", max_epochs=2), out=path,
                              progress=False).checkpoint
