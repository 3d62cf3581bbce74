"""The Foxglove server node with real processes: what a viewer gets, and who gets nothing."""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import struct
import time
from pathlib import Path

import aiohttp

from nmrm_ros.testing.graph import finish, start

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "test-token-123"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, timeout: float = 30.0) -> None:
    """Until something listens on 127.0.0.1:`port` (the server node has started)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.2)


async def _handshake(port: int, token: str = TOKEN, headers: dict | None = None) -> int:
    """The HTTP status of a WebSocket handshake (101: accepted)."""
    async with aiohttp.ClientSession() as session:
        try:
            async with session.ws_connect(f"ws://127.0.0.1:{port}/?token={token}", headers=headers or {},
                                          protocols=("foxglove.websocket.v1",)) as ws:
                await ws.close()
                return 101
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status


async def _view_arena(port: int, origin: str | None) -> tuple:
    """Connect as a viewer; wait for /nmrm/viz/arena to be advertised, subscribe, return
    (server info, the advertised topics, the first message's payload)."""
    headers = {"Origin": origin} if origin else {}
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(f"ws://127.0.0.1:{port}/?token={TOKEN}", headers=headers,
                                      protocols=("foxglove.websocket.v1",)) as ws:
            info = json.loads((await ws.receive(timeout=10)).data)
            channels: dict = {}
            deadline = time.monotonic() + 30
            while "/nmrm/viz/arena" not in channels and time.monotonic() < deadline:
                msg = await ws.receive(timeout=30)
                data = json.loads(msg.data)
                if data["op"] == "advertise":
                    channels.update({c["topic"]: c for c in data["channels"]})
            arena = channels["/nmrm/viz/arena"]
            await ws.send_json({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": arena["id"]}]})
            while True:
                msg = await ws.receive(timeout=10)
                if msg.type == aiohttp.WSMsgType.BINARY:
                    opcode, sub, _stamp = struct.unpack_from("<BIQ", msg.data)
                    assert (opcode, sub) == (1, 7)
                    return info, channels, bytes(msg.data[13:])


def test_foxglove_server_serves_the_graph_to_its_owner_only(ros_domain):
    """A visualizer publishes the arena (transient local) before anyone looks; the Foxglove server
    picks the topic up and a viewer that subscribes later gets it, as CDR that decodes to the same
    MarkerArray with the ros2msg schema it advertised. A wrong token, another web page's Origin and
    a rebinding Host get nothing; the Foxglove web app's Origin with the token gets in."""
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray

    port = _free_port()
    viz = start("visualizer", task="key")
    server = start("foxglove_server", port=port, token=TOKEN, discovery_period=0.2)
    try:
        _wait_for_port(port)
        assert asyncio.run(_handshake(port, token="wrong")) == 401
        assert asyncio.run(_handshake(port, headers={"Origin": "http://evil.example"})) == 403
        assert asyncio.run(_handshake(port, headers={"Host": "evil.example:80"})) == 403
        info, channels, payload = asyncio.run(_view_arena(port, origin=None))
        assert info["op"] == "serverInfo" and info["capabilities"] == []
        arena = channels["/nmrm/viz/arena"]
        assert (arena["encoding"], arena["schemaName"], arena["schemaEncoding"]) == (
            "cdr", "visualization_msgs/msg/MarkerArray", "ros2msg")
        assert "MSG: visualization_msgs/Marker" in arena["schema"]
        markers = deserialize_message(payload, MarkerArray).markers
        assert {"treasure", "key", "bounds"} <= {m.ns for m in markers}
        assert asyncio.run(_view_arena(port, origin="https://app.foxglove.dev"))[2] == payload
    finally:
        for p in (server, viz):
            p.send_signal(signal.SIGINT)
        (code, out), _ = finish(server), finish(viz)
    assert code == 0, out
    assert f"ws://127.0.0.1:{port}/?token={TOKEN}" in out and "serving /nmrm/viz/arena" in out, out


def test_the_layout_shows_only_topics_the_graph_publishes():
    """config/foxglove/nmrm_layout.json: every topic it names is one the graph publishes and the
    Foxglove server serves by default."""
    from nmrm_ros.nodes.foxglove_server_node import DEFAULT_TOPICS

    layout = json.loads((ROOT / "config" / "foxglove" / "nmrm_layout.json").read_text())
    named = set()
    for panel in layout["configById"].values():
        named |= set(panel.get("topics", {}))
        named |= {p["value"].split(".")[0] for p in panel.get("paths", [])}
        named |= {panel[k] for k in ("topicToRender", "topicPath") if k in panel}
        named |= {panel["imageMode"]["imageTopic"]} if "imageTopic" in panel.get("imageMode", {}) else set()
    panels = set(layout["configById"])
    assert {"3D!nmrm_arena", "Plot!nmrm_reward"} <= panels
    assert named and named <= set(DEFAULT_TOPICS), named - set(DEFAULT_TOPICS)
    viz = (ROOT / "nmrm_ros" / "nodes" / "visualizer_node.py").read_text()
    published = {t for t in named if t.startswith("/nmrm/viz/") and t.removeprefix("/nmrm/viz/") in viz}
    assert published == {t for t in named if t.startswith("/nmrm/viz/")}


async def _first_message(port: int, topic: str) -> tuple:
    """Connect, subscribe to `topic` once advertised; (its channel, the first message's payload)."""
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(f"ws://127.0.0.1:{port}/?token={TOKEN}",
                                      protocols=("foxglove.websocket.v1",)) as ws:
            channels: dict = {}
            deadline = time.monotonic() + 60
            while topic not in channels and time.monotonic() < deadline:
                data = json.loads((await ws.receive(timeout=60)).data)
                if data["op"] == "advertise":
                    channels.update({c["topic"]: c for c in data["channels"]})
            await ws.send_json({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels[topic]["id"]}]})
            while True:
                msg = await ws.receive(timeout=30)
                if msg.type == aiohttp.WSMsgType.BINARY:
                    return channels[topic], bytes(msg.data[13:])


def test_a_recorded_bag_is_watched_through_the_same_server(ros_domain, tmp_path):
    """watch_bag.launch.yaml: a bag of Key episodes, replayed in a loop, becomes the visual topics
    the layout shows (the agent's pose in the map frame), served by the Foxglove server."""
    import os
    import subprocess

    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import deserialize_message

    from nmrm_ros.testing.graph import executable

    bag = tmp_path / "key_bag"
    made = subprocess.run([executable("nmrm"), "dataset", "generate", "--task", "key", "--episodes", "3",
                           "--out", str(bag)], capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stdout + made.stderr
    port = _free_port()
    proc = subprocess.Popen([executable("nmrm"), "launch", str(ROOT / "launch_scripts" / "watch_bag.launch.yaml"),
                             f"bag:={bag}", "task:=key", "rate:=0.0", "loop:=true", f"port:={port}",
                             f"token:={TOKEN}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        _wait_for_port(port)
        channel, payload = asyncio.run(_first_message(port, "/nmrm/viz/pose"))
        pose = deserialize_message(payload, PoseStamped)
        assert channel["schemaName"] == "geometry_msgs/msg/PoseStamped" and pose.header.frame_id == "map"
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "interrupted by SIGINT: 3 node(s) stopped" in out, out[-3000:]
