"""Two "machines" on one Linux host: network namespaces joined by veth links (root only), for
the multi-host tests and bench/split_graph.py (root only). `make_hosts` creates them, `remove_hosts` deletes
them; `in_host` runs a command inside one."""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass


class HostsUnavailable(Exception):
    """Network namespaces cannot be made here (not root, no `ip`, or the kernel refuses)."""


@dataclass
class Hosts:
    robot: str
    robot_ip: str
    workstation: str
    workstation_ip: str
    robot_link: str
    workstation_link: str


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


def make_hosts(routed: bool):
    """Two namespaces on one link (a LAN: multicast reaches the other side), or, if `routed`, on
    two subnets joined by a router namespace (unicast is forwarded, multicast is not)."""
    if os.geteuid() != 0:
        raise HostsUnavailable("creating network namespaces needs root")
    if shutil.which("ip") is None:
        raise HostsUnavailable("needs iproute2's `ip`")
    tag = os.getpid() % 100000
    robot, workstation, router = f"nmrm{tag}r", f"nmrm{tag}w", f"nmrm{tag}x"
    link_r, link_w = f"nv{tag}r", f"nv{tag}w"
    a, b = 1 + tag % 120, 121 + tag % 120
    namespaces = [robot, workstation] + ([router] if routed else [])
    if routed:
        hosts = Hosts(robot, f"10.231.{a}.1", workstation, f"10.231.{b}.1", link_r, link_w)
    else:
        hosts = Hosts(robot, f"10.231.{a}.1", workstation, f"10.231.{a}.2", link_r, link_w)
    try:
        for ns in namespaces:
            _ip("netns", "add", ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        if routed:
            for ns, link, net in ((robot, link_r, a), (workstation, link_w, b)):
                _ip("link", "add", link, "type", "veth", "peer", "name", link + "x")
                _ip("link", "set", link, "netns", ns)
                _ip("link", "set", link + "x", "netns", router)
                _ip("-n", ns, "addr", "add", f"10.231.{net}.1/24", "dev", link)
                _ip("-n", router, "addr", "add", f"10.231.{net}.254/24", "dev", link + "x")
                _ip("-n", ns, "link", "set", link, "up")
                _ip("-n", router, "link", "set", link + "x", "up")
                _ip("-n", ns, "route", "add", "default", "via", f"10.231.{net}.254")
            subprocess.run(["ip", "netns", "exec", router, "sh", "-c", "echo 1 > /proc/sys/net/ipv4/ip_forward"],
                           check=True, capture_output=True, text=True)
        else:
            _ip("link", "add", link_r, "type", "veth", "peer", "name", link_w)
            for ns, link, address in ((robot, link_r, hosts.robot_ip), (workstation, link_w, hosts.workstation_ip)):
                _ip("link", "set", link, "netns", ns)
                _ip("-n", ns, "addr", "add", f"{address}/24", "dev", link)
                _ip("-n", ns, "link", "set", link, "up")
                _ip("-n", ns, "route", "add", "default", "dev", link)
    except subprocess.CalledProcessError as exc:
        for ns in namespaces:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        raise HostsUnavailable(f"cannot create network namespaces here: {exc.stderr.strip()}")
    return hosts, namespaces



def remove_hosts(namespaces: list) -> None:
    for ns in namespaces:
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def in_host(ns: str, env: dict, *cmd: str) -> subprocess.Popen:
    """`cmd` run inside namespace `ns` with environment `env`, output piped (text), own session."""
    return subprocess.Popen(["ip", "netns", "exec", ns, *cmd], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
