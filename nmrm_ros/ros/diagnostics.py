"""Every node's health on `/diagnostics` (diagnostic_msgs/DiagnosticArray), once a second.

The standard topic of ROS 2 tools (`ros2 topic echo /diagnostics`, rqt_runtime_monitor, Foxglove's
Diagnostics panel, diagnostic_aggregator): one DiagnosticStatus per node, named
`nmrm: <node's fully qualified name>`, with the node's counters as key/values and, for the counter
named by `rate_of`, its rate per second over the last period. The level is WARN while the node's
`warn()` returns a message (e.g. broken episodes, dropped actions), or while an image task's
observation images were refused or missing (`NmrmNode.subscribe_steps`), else OK.

    Diagnostics(node, lambda: {"steps": n.steps, "broken_episodes": n.broken}, rate_of="steps",
                warn=lambda: "3 broken episode(s)" if n.broken else None)
"""

from __future__ import annotations

import time
from typing import Callable

TOPIC = "/diagnostics"
PERIOD_S = 1.0


class Diagnostics:
    """Publishes `node`'s status on /diagnostics every `period` s.

    values: () -> {key: value} of the node's counters and state (values shown with str()).
    rate_of: a key of `values` that counts up; its rate (per s) is added as `<key>_per_second`.
    warn: () -> a message while something is wrong (level WARN), else None.
    The status message is the rate (or "running"), then the warning.
    """

    def __init__(self, node, values: Callable[[], dict], rate_of: str | None = None,
                 warn: Callable[[], str | None] | None = None, hardware_id: str = "", period: float = PERIOD_S) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.node, self.values, self.rate_of = node, values, rate_of
        self.warn, self.hardware_id = warn, hardware_id
        self.name = f"nmrm: {node.get_fully_qualified_name()}"
        self.window: tuple | None = None  # (monotonic time, count) at the last publication
        self.pub = node.create_publisher(DiagnosticArray, TOPIC, 10)
        self.timer = node.create_timer(period, self.publish)

    def status(self):
        """This period's DiagnosticStatus."""
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

        values = dict(self.values())
        message = "running"
        if self.rate_of is not None:
            now, count = time.monotonic(), float(values.get(self.rate_of, 0))
            since, before = self.window or (now, count)
            rate = (count - before) / (now - since) if now > since else 0.0
            self.window = (now, count)
            values[f"{self.rate_of}_per_second"] = f"{rate:.2f}"
            message = f"{rate:.1f} {self.rate_of.replace('_', ' ')}/s"
        problem = self.warn() if self.warn is not None else None
        pairings = getattr(self.node, "image_pairings", [])  # an image task's steps joined with their images
        if pairings:
            refused, unpaired = sum(p.bad_images for p in pairings), sum(p.unpaired for p in pairings)
            values.update(observation_images_refused=refused, steps_without_image=unpaired)
            if refused or unpaired:
                lost = f"{refused} observation image(s) refused, {unpaired} step(s) without their image"
                problem = f"{problem}; {lost}" if problem else lost
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN if problem else DiagnosticStatus.OK, name=self.name,
            hardware_id=self.hardware_id, message=f"{message}; {problem}" if problem else message,
            values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])

    def publish(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        out = DiagnosticArray(status=[self.status()])
        out.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(out)
