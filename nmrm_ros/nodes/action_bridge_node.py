"""action_bridge: the agent's actions out to a robot as geometry_msgs/Twist (or TwistStamped).

Reads the `action:` section of a robot spec (`spec`; `nmrm_ros.ros.robot_spec`): a table from
discrete action indices to twist fields, or a map from a continuous action's values to twist
fields with limits (clipped). Every AgentAction on `nmrm/action` sets the command; `rate` times
a second the current command is published on the spec's topic (robots expect a stream). The
safe stop: a zero twist is sent instead when no action came for `timeout` s, and at once when an
episode's final observation (terminated or truncated) arrives, until the next episode's first
action. An action that does not fit (an unknown index, a wrong size, NaN) is dropped with a
counted warning, and the robot stops as if none came. On shutdown a last zero twist is sent.
"""

from __future__ import annotations

import math
import time


from nmrm_msgs.msg import AgentAction, EnvObservation

from ..ros.node_base import NmrmNode
from ..ros.node_main import EXIT_WITH_UPSTREAM, NodeError, Param, require_robot_spec
from ..ros.topics import ACTION, OBSERVATION, STEP_QOS

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "spec": Param("", "robot spec YAML (its action: section; see nmrm_ros.ros.robot_spec)"),
    "frame_id": Param("base_link", "header frame of TwistStamped commands"),
}

WARN_EVERY_S = 5.0


class ActionBridgeNode(NmrmNode):
    executable = "action_bridge"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        from geometry_msgs.msg import Twist, TwistStamped

        self.spec = require_robot_spec(p["spec"])
        if not self.spec.discrete and not self.spec.continuous_fields:
            raise NodeError(f"{p['spec']}: the action section maps no action (give discrete: or continuous:)")
        self.frame_id = str(p["frame_id"])
        self.kind = TwistStamped if self.spec.stamped else Twist
        self.pub = self.create_publisher(self.kind, self.spec.action_topic, 10)
        self.command: dict = {}
        self.commanded_at = 0.0
        self.stopped_for = None  # the episode whose final observation stopped the robot
        self.dropped = 0
        self.stops = 0
        self.warned_at = 0.0
        subs = [self.create_subscription(AgentAction, ACTION, self.on_action, STEP_QOS),
                self.create_subscription(EnvObservation, OBSERVATION, self.on_observation, STEP_QOS)]
        self.exit_with_upstream(subs)
        self.create_timer(1.0 / self.spec.action_rate, self.on_tick)
        self.get_logger().info(
            f"actions -> {self.kind.__name__} on {self.spec.action_topic} at {self.spec.action_rate:g} Hz "
            f"({'table of ' + str(len(self.spec.discrete)) + ' actions' if self.spec.discrete else 'fields ' + ', '.join(self.spec.continuous_fields)}); "
            f"zero twist after {self.spec.action_timeout:g} s without an action and at each episode's end")
        self.diagnose(lambda: {"dropped_actions": self.dropped, "safe_stops": self.stops},
            warn=lambda: f"{self.dropped} action(s) dropped" if self.dropped else None)

    def on_action(self, msg: AgentAction) -> None:
        if self.stopped_for is not None and msg.episode <= self.stopped_for:
            return  # a late answer about an episode that has ended
        values = list(msg.action)
        try:
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"action {values} is not finite")
            self.command = self.spec.twist(values)
        except ValueError as exc:
            self.dropped += 1
            self.command = {}
            if time.monotonic() - self.warned_at >= WARN_EVERY_S:
                self.warned_at = time.monotonic()
                self.get_logger().warning(f"action of episode {msg.episode} step {msg.step} dropped "
                                          f"({self.dropped} so far): {exc}")
            return
        self.stopped_for = None
        self.commanded_at = time.monotonic()

    def on_observation(self, msg: EnvObservation) -> None:
        if msg.terminated or msg.truncated:
            self.stopped_for = int(msg.episode)
            self.command = {}
            self.send({})  # at once, not at the next tick
            self.stops += 1

    def on_tick(self) -> None:
        fresh = self.command and time.monotonic() - self.commanded_at <= self.spec.action_timeout
        self.send(self.command if fresh else {})

    def send(self, fields: dict) -> None:
        out = self.kind()
        twist = out.twist if self.spec.stamped else out
        for name, value in fields.items():
            part, axis = name.split(".")
            setattr(getattr(twist, part), axis, float(value))
        if self.spec.stamped:
            out.header.stamp = self.get_clock().now().to_msg()
            out.header.frame_id = self.frame_id
        self.pub.publish(out)

    def close(self) -> None:
        try:
            self.send({})  # the robot is left standing
        except Exception:  # noqa: BLE001 - the context may be gone at shutdown
            pass
        self.get_logger().info(f"{self.stops} episode end stop(s), {self.dropped} action(s) dropped")


def main(args=None) -> int:
    return ActionBridgeNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
