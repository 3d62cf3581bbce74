"""replay: publishes a bag's messages on their topics, as serialized messages.

rate > 0: at the recorded timing scaled by `rate` (2.0 = twice as fast); rate = 0: as fast as
possible; the topics are reliable and keep-all (nmrm_ros.ros.topics), so subscribers queue what
they have not taken yet and nothing is lost. `topics` filters (empty = all; an observation or
reward-step topic brings its graph's observation images, if the bag has them: an image task's
states are incomplete without them); `loop` starts over at the end. Before
the first message the node waits for `wait_for_subscribers` subscribers on every replayed topic.
Without `loop`, the node exits with code 0 once every subscriber has acknowledged the last
message (at most 30 s). Before the first message the
node also waits for the subscriptions of every node named in `wait_for_nodes`. Messages are
published in slices of at most 20 ms, so Ctrl-C or SIGTERM stops a replay at once (exit 0).
"""

from __future__ import annotations

import time


from ..bags.reader import BagError, bag_summary, iter_raw
from ..bags.schemas import with_observation_images
from ..ros.field_paths import message_class
from ..ros.node_base import NmrmNode
from ..ros.node_main import NodeError, Param, subscribed_nodes
from ..ros.topics import STEP_QOS

RETRY_TIMEOUT_S = 60.0  # a full writer history: how long to wait for subscribers to take messages
ACK_TIMEOUT_S = 30.0  # after the last message: how long to wait for subscribers to acknowledge it

PARAMETERS = {
    "bag": Param("", "bag directory (or .mcap file) to replay"),
    "rate": Param(0.0, "playback speed factor of the recorded timing; 0 = as fast as subscribers take", 0.0),
    "topics": Param([""], "topics to replay (empty = all)"),
    "loop": Param(False, "start over at the end"),
    "wait_for_subscribers": Param(1, "subscribers to wait for on each replayed topic", 0),
    "wait_for_nodes": Param([""], "names of nodes whose subscriptions to wait for (any replayed topic)"),
    "startup_timeout": Param(60.0, "seconds to wait for subscribers", 0.001),
    "start_delay": Param(0.0, "seconds to wait once subscribers are there (lets downstream endpoints match)", 0.0),
}


class ReplayNode(NmrmNode):
    executable = "replay"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        if not p["bag"]:
            raise NodeError("parameter bag is required")
        self.path = p["bag"]
        try:
            summary = bag_summary(self.path)
        except BagError as exc:
            raise NodeError(str(exc)) from None
        wanted = [t for t in p["topics"] if t]
        missing = [t for t in wanted if t not in summary]
        if missing:
            raise NodeError(f"topics {missing} are not in the bag (it has {sorted(summary)})")
        # an image task's observations bring their images (bags.schemas.with_observation_images)
        self.topics = with_observation_images(wanted, available=summary) if wanted else sorted(summary)
        self.pubs = {t: self.create_publisher(message_class(summary[t][0]), t, STEP_QOS) for t in self.topics}
        self.rate = float(p["rate"])
        self.loop = bool(p["loop"])
        self.wait_for = int(p["wait_for_subscribers"])
        self.wait_for_nodes = {n for n in p["wait_for_nodes"] if n}
        self.deadline = time.monotonic() + float(p["startup_timeout"])
        self.start_delay = float(p["start_delay"])
        self.ready_at = None
        self.published = 0
        self.retries = 0
        self.messages = None  # the bag's messages while playing
        self.timer = self.create_timer(0.05, self.on_timer)
        self.get_logger().info(f"replaying {self.path}: {', '.join(self.topics)} "
                               f"(rate {self.rate or 'as fast as subscribers take'})")
        self.diagnose(lambda: {"messages": self.published, "retries": self.retries},
            rate_of="messages")

    def on_timer(self) -> None:
        if self.messages is not None:
            return self.play_some()
        subscribed = set().union(*(subscribed_nodes(self, pub.topic_name) for pub in self.pubs.values()))
        if (any(pub.get_subscription_count() < self.wait_for for pub in self.pubs.values())
                or not subscribed >= self.wait_for_nodes) and self.ready_at is None:
            if time.monotonic() > self.deadline:
                self.get_logger().error("start-up timeout waiting for subscribers")
                self.exit_code = 1
            return
        self.ready_at = self.ready_at or time.monotonic()
        if time.monotonic() - self.ready_at < self.start_delay:
            return
        self.timer.cancel()
        self.start_pass()
        self.timer = self.create_timer(0.001, self.on_timer)

    def start_pass(self) -> None:
        self.messages = iter_raw(self.path, self.topics, current=True)  # older definitions re-encoded
        self.next = None
        self.first_ns = None
        self.start_wall = time.monotonic()

    def play_some(self, budget_s: float = 0.02) -> None:
        """Publish what is due, for at most `budget_s`, then return to the executor (so Ctrl-C and
        SIGTERM stop a long replay at once)."""
        until = time.monotonic() + budget_s
        try:
            while time.monotonic() < until:
                if self.next is None:
                    self.next = next(self.messages, None)
                    if self.next is None:
                        if self.loop:
                            self.start_pass()
                            continue
                        self.finish_playing()
                        return
                m = self.next
                if self.rate > 0:
                    self.first_ns = m.log_time_ns if self.first_ns is None else self.first_ns
                    due = self.start_wall + (m.log_time_ns - self.first_ns) / 1e9 / self.rate
                    if time.monotonic() < due:
                        return
                self._publish(self.pubs[m.topic], m.data)
                self.published += 1
                self.next = None
        except BagError as exc:
            self.get_logger().error(str(exc))
            self.timer.cancel()
            self.exit_code = 1

    def finish_playing(self) -> None:
        """After the last message: wait until every subscriber has acknowledged what it was sent
        (at most ACK_TIMEOUT_S; a reliable writer that exits earlier takes the unacknowledged
        tail with it), then exit 0."""
        from rclpy.duration import Duration

        self.timer.cancel()
        deadline = time.monotonic() + ACK_TIMEOUT_S
        for pub in self.pubs.values():
            left = max(deadline - time.monotonic(), 0.0)
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                self.get_logger().warning(f"subscribers of {pub.topic_name} had not acknowledged every message "
                                          f"{ACK_TIMEOUT_S:.0f} s after the last: they may miss the end")
        self.get_logger().info(f"replayed {self.published} messages"
                               + (f" ({self.retries} retries while subscribers caught up)" if self.retries else ""))
        self.exit_code = 0

    def close(self) -> None:
        if self.exit_code is None and self.messages is not None:
            self.get_logger().info(f"stopped after {self.published} messages")

    def _publish(self, pub, data: bytes) -> None:
        """Publish; while the writer's keep-all history is full (bounded by the DDS resource
        limits: rate 0 outpaces slow subscribers), retry until they catch up, up to
        RETRY_TIMEOUT_S."""
        from rclpy._rclpy_pybind11 import RCLError

        deadline = None
        while True:
            try:
                pub.publish(data)
                return
            except RCLError:
                deadline = deadline or time.monotonic() + RETRY_TIMEOUT_S
                if time.monotonic() > deadline:
                    raise BagError(f"subscribers of {pub.topic_name} took nothing for {RETRY_TIMEOUT_S:.0f} s; "
                                   f"stopped after {self.published} messages") from None
                self.retries += 1
                time.sleep(0.01)


def main(args=None) -> int:
    return ReplayNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
