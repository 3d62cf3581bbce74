"""foxglove_server: the running graph in Foxglove, through a WebSocket only its owner can open.

Subscribes to `topics` (as serialized messages; a topic is picked up once it appears in the graph,
with QoS that matches its publishers: a transient-local map such as nmrm/viz/arena reaches a viewer
that connects later) and serves them with the Foxglove WebSocket protocol on `host`:`port`
(nmrm_ros.viewer.foxglove_server: the `Host` must name this server, the access token must be in the
URL, a browser's Origin must be one of `allowed_origins`). At start it prints the URL with the token
and the link that opens it in the Foxglove web app; config/foxglove/nmrm_layout.json is the layout
(3D view of the arena, pose and path; plots of the served reward, its std and the hidden state;
the diagnostics). The token is `token`, else one generated per start. Read-only. With `certfile`
and `keyfile` it serves WSS only; beyond loopback without them it does not start unless
`trusted_network` (nmrm_ros.tls).

    ros2 run nmrm_ros foxglove_server            # beside any graph; or robot_bridge.launch.yaml foxglove:=true
"""

from __future__ import annotations

import secrets
import time
from urllib.parse import quote


from ..ros.diagnostics import TOPIC as DIAGNOSTICS
from ..ros.field_paths import message_class
from ..ros.msg_schema import ros2msg_schema
from ..ros.node_base import NmrmNode
from ..ros.node_main import EXIT_WITH_UPSTREAM, SERVER_TLS, Param, start_server
from ..web_server import is_any_address

DEFAULT_TOPICS = ["/nmrm/viz/arena", "/nmrm/viz/pose", "/nmrm/viz/path", "/nmrm/viz/reward",
                  "/nmrm/viz/reward_std", "/nmrm/viz/hidden", "/diagnostics", "/nmrm/reward_step",
                  "/nmrm/trajectory_return", "/nmrm/observation_image"]

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "host": Param("127.0.0.1", "address to serve on (keep loopback unless you must: the token then guards it alone)"),
    "port": Param(8765, "TCP port (0: any free port, printed at start)", 0),
    "token": Param("", "access token clients must give as ?token= ('' = a new random one each start)"),
    "allowed_origins": Param(["https://app.foxglove.dev"], "web origins allowed to connect (a client without an "
                                                           "Origin, e.g. the desktop app, needs the token only)"),
    "topics": Param(DEFAULT_TOPICS, "topics to serve, subscribed once they appear in the graph"),
    "discovery_period": Param(1.0, "seconds between looks for new topics", 0.05),
    **SERVER_TLS,
}


def matching_qos(publishers: list):
    """QoS that matches every publisher of a topic: best effort if any is, transient local only if
    all are (a transient-local subscription does not match a volatile publisher)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=10)
    if any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if publishers and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


class FoxgloveServerNode(NmrmNode):
    executable = "foxglove_server"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        from ..viewer.foxglove_server import FoxgloveServer

        self.messages_received = 0  # of the upstream topics (exit_with_upstream), /diagnostics not counted
        self.forwarded = 0
        super().__init__()
        p = self.params
        self.wanted = [t if t.startswith("/") else self.resolve_topic_name(t) for t in p["topics"]]
        self.served: dict = {}  # topic -> (channel id, subscription)
        self.subs: list = []  # the subscriptions, as topics appear
        self.skipped: set = set()
        host = str(p["host"])
        allowed_hosts: set | None = None if is_any_address(host) else set()
        self.server = FoxgloveServer(p["token"] or secrets.token_urlsafe(24), tuple(p["allowed_origins"]),
                                     allowed_hosts)
        self.web = start_server(self.server.app, p)
        self.server.attach(self.web.loop)
        if allowed_hosts is not None:  # the Host a client sends for this address and port
            allowed_hosts.update(self.web.allowed_hosts())
        url = self.web.url("/").replace("http", "ws", 1) + f"?token={self.server.token}"
        self.tell_starter(f"Foxglove: {url}  (open in the web app: https://app.foxglove.dev/?ds=foxglove-websocket"
                               f"&ds.url={quote(url, safe='')}; layout config/foxglove/nmrm_layout.json)")
        self.create_timer(float(p["discovery_period"]), self.discover)
        self.exit_with_upstream(self.subs)
        self.diagnose(lambda: {"clients": len(self.server.clients), "refused_connections": self.server.refused,
            "channels": len(self.served), "messages": self.forwarded},
            rate_of="messages")
        self.discover()

    def discover(self) -> None:
        """Serve each wanted topic that has appeared in the graph since the last look."""
        from rclpy.qos import DurabilityPolicy

        types = dict(self.get_topic_names_and_types())
        for topic in self.wanted:
            if topic in self.served or topic in self.skipped or topic not in types:
                continue
            type_name = types[topic][0]
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            try:
                cls, schema = message_class(type_name), ros2msg_schema(type_name)
            except ValueError as exc:  # not installed here
                self.skipped.add(topic)
                self.get_logger().warning(f"not serving {topic}: {exc}")
                continue
            qos = matching_qos(publishers)
            cid = self.server.add_channel(topic, type_name, schema,
                                          latched=qos.durability == DurabilityPolicy.TRANSIENT_LOCAL)
            upstream = topic != DIAGNOSTICS  # /diagnostics is published by this node too
            sub = self.create_subscription(cls, topic, lambda data, c=cid, u=upstream: self.forward(c, data, u),
                                           qos, raw=True)
            self.served[topic] = (cid, sub)
            if upstream:
                self.subs.append(sub)
            self.get_logger().info(f"serving {topic} ({type_name})")

    def forward(self, channel_id: int, data: bytes, upstream: bool = True) -> None:
        self.forwarded += 1
        self.messages_received += upstream
        self.server.publish(channel_id, time.time_ns(), bytes(data))

    def close(self) -> None:
        self.web.stop()


def main(args=None) -> int:
    return FoxgloveServerNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
