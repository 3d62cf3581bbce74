"""recorder: records topics to a rosbag2-compatible MCAP bag, as serialized messages (no re-encoding).

The bag is a directory (`output`) with metadata.yaml and one .mcap (ros2 profile, zstd chunks,
schemas embedded): `ros2 bag info/play`, Foxglove, the `mcap` CLI and `rosbags` read it. Each
message is logged at its receive time. Ctrl-C / SIGTERM close the bag cleanly, with every message
received before them (for at most 2 s more). Every
`flush_period` s the chunk in progress is ended and the file flushed to disk, so after a hard kill
`nmrm bag repair OUTPUT` recovers everything received up to `flush_period` s before it. On close it logs how many messages it wrote and its own write
rate (messages over the time from its first to its last write). A recording of nothing (e.g. the
rest of a launch failed at start) is removed at close, so it leaves no empty bag in the way.
"""

from __future__ import annotations

import time


from ..bags.schemas import TOPIC_TYPES, split_topic, with_observation_images
from ..bags.writer import BagWriter
from ..ros.field_paths import message_class
from ..ros.node_base import NmrmNode
from ..ros.node_main import EXIT_WITH_UPSTREAM, NodeError, Param
from ..ros.topics import STEP_QOS

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "output": Param("", "bag directory to create (default: bags/recording_<UTC time>)"),
    "topics": Param(list(TOPIC_TYPES), "topics to record: nmrm topics, in any namespace (an observation or "
                                       "reward-step topic brings its graph's nmrm/observation_image)"),
    "namespaces": Param([""], "record `topics` under each of these namespaces (e.g. [/robot1, /robot2]); "
                              "'' = as given"),
    "flush_period": Param(1.0, "seconds between flushes to disk (the chunk in progress is ended)", 0.001),
    "observation_wait": Param(5.0, "seconds at most to wait, before subscribing to the observation topic, until "
                                   "its publishers are known here (so the first steps are not lost; 0: at once)", 0.0),
    "chunk_size": Param(262144, "MCAP chunk size in bytes (smaller: less lost on a hard kill)", 1024),
}


class RecorderNode(NmrmNode):
    executable = "recorder"
    PARAMETERS = PARAMETERS
    drain_on_stop = 2.0  # messages received before Ctrl-C are in the bag

    def __init__(self) -> None:
        self.messages_received = 0
        self.first_write = self.last_write = None  # perf_counter() of the first / last write
        self.bag = None
        super().__init__()
        p = self.params
        output = p["output"] or time.strftime("bags/recording_%Y%m%d_%H%M%S", time.gmtime())
        topics = with_observation_images([ns.rstrip("/") + "/" + t.lstrip("/") if ns else t
                                          for ns in (p["namespaces"] or [""]) for t in p["topics"]])
        resolved = {}
        for t in topics:
            name = self.resolve_topic_name(t)
            try:
                resolved[t] = (name, split_topic(name)[1])
            except ValueError as exc:
                raise NodeError(f"cannot record {t!r}: {exc}") from None
        try:
            self.bag = BagWriter(output, chunk_size=int(p["chunk_size"]))
        except (FileExistsError, OSError) as exc:
            raise NodeError(str(exc)) from None
        self.subs = []
        self.pending = []  # observation topics, subscribed once their publishers are known here
        for topic, (name, type_name) in resolved.items():
            self.bag.add_topic(name, type_name)
            if name.endswith("/nmrm/observation"):
                self.pending.append((topic, name, type_name))
            else:
                self._subscribe(topic, name, type_name)
        # A producer (env_sim, observation_bridge) starts its first episode once it sees our
        # observation subscription; it cannot see whether *our* side has matched its publisher, and
        # under load that took more than its start_delay: the recording lost the first steps of
        # episode 0 (the fake-robot graph, 3 graphs at once on 2 cores: 3 of 75 runs). So the
        # observation subscription comes last, once this node knows the topic's publishers (it then
        # matches them as it is created) and its other subscriptions have matched every publisher
        # it knows of theirs, or after `observation_wait` s.
        self.wait_started = time.monotonic()
        self.observation_wait = float(p["observation_wait"])
        self.pending_timer = self.create_timer(0.05, self._subscribe_observations) if self.pending else None
        self.create_timer(float(p["flush_period"]), self.bag.flush)
        self.exit_with_upstream(self.subs)
        self.get_logger().info(f"recording {len(resolved)} topic(s) to {output}")
        self.diagnose(lambda: {"messages": self.messages_received, "bag": output},
            rate_of="messages")

    def _subscribe(self, topic: str, name: str, type_name: str) -> None:
        cb = (lambda data, n=name, t=type_name: self.on_message(n, t, data))
        self.subs.append(self.create_subscription(message_class(type_name), topic, cb, STEP_QOS, raw=True))

    def _subscribe_observations(self) -> None:
        """Subscribe to the pending observation topics once this node knows their publishers and
        has matched every publisher it knows of its other topics (or `observation_wait` s passed)."""
        known = all(self.count_publishers(name) > 0 for _, name, _ in self.pending)
        matched = all(s.get_publisher_count() >= self.count_publishers(s.topic_name) for s in self.subs)
        waited = time.monotonic() - self.wait_started
        if not (known and matched) and waited < self.observation_wait:
            return
        self.destroy_timer(self.pending_timer)
        self.pending_timer = None
        for topic, name, type_name in self.pending:
            self._subscribe(topic, name, type_name)
        self.pending = []

    def on_message(self, topic: str, type_name: str, data: bytes) -> None:
        self.bag.write_cdr(topic, type_name, data, self.get_clock().now().nanoseconds)
        self.messages_received += 1
        self.last_write = time.perf_counter()
        if self.first_write is None:
            self.first_write = self.last_write

    def write_rate(self) -> str:
        """'N messages written in S s (R msg/s)', from the recorder's own count and clock."""
        if self.messages_received < 2:
            return f"{self.messages_received} messages written"
        span = self.last_write - self.first_write
        return (f"{self.messages_received} messages written in {span:.3f} s "
                f"({(self.messages_received - 1) / span:.0f} msg/s)")

    def close(self) -> None:
        if self.bag is not None and not self.bag.closed:
            if self.messages_received == 0:  # e.g. the rest of a launch failed at start: leave no debris
                self.bag.discard()
                self.get_logger().info(f"recorded nothing: removed the empty bag {self.bag.path}")
                return
            self.bag.close()
            counts = ", ".join(f"{t} {n}" for t, n in self.bag.counts.items())
            self.get_logger().info(f"closed {self.bag.path}: {self.messages_received} messages ({counts}); "
                                   f"{self.write_rate()}")


def main(args=None) -> int:
    return RecorderNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
