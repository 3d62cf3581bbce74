"""The graph split over two hosts: two network namespaces joined by a veth pair, so every message
crosses a real IP link (UDP only: Fast DDS's shared-memory transport is switched off, as it would
be unavailable between machines). env_sim + agent on one side, reward_model + labeller + recorder
on the other; discovery by multicast (the DDS default), or through a Discovery Server on a link
without multicast. The test creates and removes its own namespaces; without root it skips."""

from __future__ import annotations

import json
import os
import signal
import subprocess
from collections import Counter
from pathlib import Path

import pytest

from nmrm_ros.testing.graph import executable
from nmrm_ros.testing.netns import Hosts, HostsUnavailable, in_host, make_hosts, remove_hosts
from nmrm_ros.bags import iter_decoded, load_bag_dataset

REPO = Path(__file__).resolve().parents[1]

EPISODES = 3


def _hosts(routed: bool):
    try:
        hosts, namespaces = make_hosts(routed=routed)
    except HostsUnavailable as exc:
        pytest.skip(str(exc))
    yield hosts
    remove_hosts(namespaces)


@pytest.fixture
def lan_hosts():
    yield from _hosts(routed=False)


@pytest.fixture
def routed_hosts():
    yield from _hosts(routed=True)


def _env(**extra) -> dict:
    env = os.environ.copy()
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"  # the default of ROS 2; our test env pins LOCALHOST
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"  # no shared memory between the "machines"
    env.update(extra)
    return env


_in = in_host


def _finish(proc: subprocess.Popen, timeout: float) -> tuple:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        return None, out
    return proc.returncode, out


def _link_bytes(ns: str, link: str) -> int:
    out = subprocess.run(["ip", "-n", ns, "-s", "-j", "link", "show", link], capture_output=True,
                         text=True, check=True).stdout
    stats = json.loads(out)[0]["stats64"]
    return int(stats["rx"]["bytes"]) + int(stats["tx"]["bytes"])


def _run_split_graph(hosts: Hosts, env: dict, bag) -> None:
    launch = executable("nmrm")
    workstation = _in(hosts.workstation, env, launch, "launch",
                      str(REPO / "launch_scripts" / "workstation.launch.yaml"), "task:=key", f"out:={bag}")
    robot = _in(hosts.robot, env, launch, "launch", str(REPO / "launch_scripts" / "robot.launch.yaml"),
                "task:=key", f"episodes:={EPISODES}")
    code_r, out_r = _finish(robot, 150)
    code_w, out_w = _finish(workstation, 60)
    assert code_r == 0, f"robot side:\n{out_r}\nworkstation side:\n{out_w}"
    assert code_w == 0, f"workstation side:\n{out_w}\nrobot side:\n{out_r}"
    assert f"done: {EPISODES} episodes" in out_r, out_r
    assert "all 3 node(s) exited cleanly" in out_w, out_w

    ds, report = load_bag_dataset([bag])
    assert report.episodes_used == EPISODES and not report.skipped, str(report)
    assert report.labellers == Counter({"oracle/key": EPISODES})
    counts = Counter(type_name.rsplit("/", 1)[-1] for _, type_name, _, _ in iter_decoded(bag))
    steps = EPISODES * 101
    assert counts["EnvObservation"] == steps and counts["RewardStep"] == steps, counts
    assert counts["AgentAction"] == EPISODES * 100 and counts["OracleStep"] == EPISODES * 100, counts
    assert counts["TrajectoryReturn"] == EPISODES, counts


def _shm_segments() -> set:
    return {p.name for p in Path("/dev/shm").glob("fastrtps_*")}


def test_graph_across_two_hosts_with_multicast_discovery(ros_domain, lan_hosts, tmp_path):
    before = _shm_segments()
    _run_split_graph(lan_hosts, _env(), tmp_path / "bag")
    # no shared-memory transport: every message went over UDP, and between namespaces UDP can
    # only cross the veth link. /dev/shm is the machine's: where tests run beside this one
    # (scripts/test.sh runs two workers), their processes add segments too, so only the link's
    # bytes say it then.
    if os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") == "1":
        assert _shm_segments() <= before
    assert _link_bytes(lan_hosts.robot, lan_hosts.robot_link) > 200_000


def test_graph_across_subnets_through_a_discovery_server(ros_domain, routed_hosts, tmp_path):
    """Multicast does not cross the router between the two subnets: without the server the
    nodes never meet; with it (ROS_DISCOVERY_SERVER), the graph runs."""
    hosts = routed_hosts
    alone = _in(hosts.robot, _env(), executable("env_sim"), "--ros-args", "-p", "task:=key",
                "-p", "wait_for_subscribers:=1", "-p", "startup_timeout:=4.0")
    watcher = _in(hosts.workstation, _env(), executable("labeller_oracle"))
    code, out = _finish(alone, 30)
    os.killpg(watcher.pid, signal.SIGINT)
    _finish(watcher, 10)
    assert code != 0 and "waiting for 1 subscriber" in out, out

    address = f"{hosts.workstation_ip}:11811"
    env = _env(ROS_DISCOVERY_SERVER=address)
    server = _in(hosts.workstation, env, executable("nmrm"), "discovery-server", "--address",
                 hosts.workstation_ip, "--port", "11811")
    try:
        _run_split_graph(hosts, env, tmp_path / "bag")
    finally:
        os.killpg(server.pid, signal.SIGINT)
        _, out = _finish(server, 10)
    assert f"UDPv4:[{hosts.workstation_ip}]:11811" in out, out
