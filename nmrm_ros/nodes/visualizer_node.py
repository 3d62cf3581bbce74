"""visualizer: the running graph in standard messages, for Foxglove, RViz and PlotJuggler.

From `nmrm/observation` and `nmrm/reward_step` of `task` it publishes, in one fixed frame
(`frame_id`, default "map"; positions are the task's x/y state dimensions, metres or arena units):
  nmrm/viz/arena       visualization_msgs/MarkerArray: the arena's bounds and zones (transient
                       local: a viewer that connects later still gets it)
  nmrm/viz/pose        geometry_msgs/PoseStamped: the agent now (heading from the state where the
                       task has one, e.g. the delivery robot's third dimension)
  nmrm/viz/path        nav_msgs/Path: this episode's path so far (cleared at each step 0)
  nmrm/viz/reward      std_msgs/Float32: the served reward r'_t
  nmrm/viz/reward_std  std_msgs/Float32: its std over the ensemble's members
  nmrm/viz/hidden      std_msgs/Float32MultiArray: the served hidden state
and `/diagnostics` (diagnostic_msgs/DiagnosticArray) once a second: steps per second, episodes,
broken episodes (observations out of order), the model version served. A task without x/y (your
own task without `xy=i/j`) gets the plottable topics and the diagnostics only.
"""

from __future__ import annotations

import math


from nmrm_msgs.msg import EnvObservation, RewardStep

from ..ros.node_base import NmrmNode
from ..ros.node_main import EXIT_WITH_UPSTREAM, Param, require_task
from ..ros.topics import OBSERVATION, REWARD_STEP, STEP_QOS

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "task": Param("key", "task of the graph (its arena and which state dimensions are x and y)"),
    "frame_id": Param("map", "the fixed frame of every pose, path and marker"),
    "heading_dim": Param(-1, "state dimension of the heading in rad (-1: none; the delivery robot: 2)", -1),
    "max_path": Param(2000, "poses kept in the path of an episode", 1),
}

VIZ = "nmrm/viz/"


class VisualizerNode(NmrmNode):
    executable = "visualizer"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        self.messages_received = 0
        super().__init__()
        p = self.params
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from std_msgs.msg import Float32, Float32MultiArray
        from visualization_msgs.msg import MarkerArray

        from ..tasks.arena import arena

        self.info = require_task(p["task"])
        self.task = p["task"]
        self.frame = str(p["frame_id"])
        self.heading_dim = int(p["heading_dim"])
        self.max_path = int(p["max_path"])
        self.arena = arena(self.task)
        self.types = {"pose": PoseStamped, "path": Path, "f32": Float32, "array": Float32MultiArray}
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.arena_pub = self.create_publisher(MarkerArray, VIZ + "arena", latched)
        self.pose_pub = self.create_publisher(PoseStamped, VIZ + "pose", 10)
        self.path_pub = self.create_publisher(Path, VIZ + "path", 10)
        self.reward_pub = self.create_publisher(Float32, VIZ + "reward", 10)
        self.std_pub = self.create_publisher(Float32, VIZ + "reward_std", 10)
        self.hidden_pub = self.create_publisher(Float32MultiArray, VIZ + "hidden", 10)
        self.path = Path()
        self.path.header.frame_id = self.frame
        self.steps = self.episodes = self.broken = 0
        self.last = None  # (episode, step) of the last observation
        self.source = ""
        subs = [self.create_subscription(EnvObservation, OBSERVATION, self.on_observation, STEP_QOS),
                self.create_subscription(RewardStep, REWARD_STEP, self.on_reward, STEP_QOS)]
        self.exit_with_upstream(subs)
        self.diagnose(lambda: {"steps": self.steps, "episodes": self.episodes, "broken_episodes": self.broken,
            "model": self.source}, rate_of="steps", hardware_id=self.task,
            warn=lambda: f"{self.broken} broken episode(s)" if self.broken else None)
        if self.arena is not None:
            self.arena_pub.publish(self.markers())
        self.get_logger().info(f"task {self.task}: {VIZ}* in frame {self.frame}"
                               + ("" if self.arena else " (no x/y: plottable topics only)") + ", /diagnostics")

    def markers(self):
        """The arena as a MarkerArray: a flat cube per zone, a line strip round the bounds."""
        from geometry_msgs.msg import Point
        from visualization_msgs.msg import Marker, MarkerArray

        colours = {"spawn": (0.8, 0.8, 0.8), "treasure": (0.95, 0.83, 0.48), "treasure row": (0.95, 0.83, 0.48),
                   "goal": (0.95, 0.83, 0.48), "key": (0.61, 0.71, 0.95), "pickup": (0.61, 0.71, 0.95),
                   "charger": (0.66, 0.88, 0.66), "pad": (0.47, 0.47, 0.47)}
        out = MarkerArray()
        for i, (x0, x1, y0, y1, kind) in enumerate(self.arena["zones"]):
            m = Marker(type=Marker.CUBE, action=Marker.ADD, id=i, ns=kind)
            m.header.frame_id = self.frame
            m.pose.position.x, m.pose.position.y, m.pose.position.z = (x0 + x1) / 2, (y0 + y1) / 2, -0.005
            m.pose.orientation.w = 1.0
            m.scale.x, m.scale.y, m.scale.z = max(x1 - x0, 1e-3), max(y1 - y0, 1e-3), 0.01
            m.color.r, m.color.g, m.color.b = colours.get(kind, (0.7, 0.7, 0.7))
            m.color.a = 0.6
            out.markers.append(m)
        if self.arena.get("bounds"):
            x0, x1, y0, y1 = self.arena["bounds"]
            m = Marker(type=Marker.LINE_STRIP, action=Marker.ADD, id=len(out.markers), ns="bounds")
            m.header.frame_id = self.frame
            m.pose.orientation.w = 1.0
            m.scale.x = 0.01
            m.color.r = m.color.g = m.color.b = 0.2
            m.color.a = 1.0
            m.points = [Point(x=float(x), y=float(y)) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))]
            out.markers.append(m)
        return out

    def on_observation(self, msg: EnvObservation) -> None:
        self.messages_received += 1
        if msg.task != self.task:
            return
        if msg.step == 0:
            self.path.poses = []
            self.episodes += 1
        elif self.last is not None and (self.last[0] != msg.episode or msg.step not in (self.last[1], self.last[1] + 1)):
            self.broken += 1
        self.last = (int(msg.episode), int(msg.step))
        self.steps += 1
        if self.arena is None:
            return
        ix, iy = self.arena["xy"]
        state = list(msg.state)
        if max(ix, iy) >= len(state):
            return
        pose = self.types["pose"]()
        pose.header.stamp, pose.header.frame_id = msg.header.stamp, self.frame
        pose.pose.position.x, pose.pose.position.y = float(state[ix]), float(state[iy])
        heading = float(state[self.heading_dim]) if 0 <= self.heading_dim < len(state) else 0.0
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(heading / 2), math.cos(heading / 2)
        self.pose_pub.publish(pose)
        self.path.header.stamp = msg.header.stamp
        self.path.poses.append(pose)
        del self.path.poses[: -self.max_path]
        self.path_pub.publish(self.path)

    def on_reward(self, msg: RewardStep) -> None:
        self.messages_received += 1
        self.source = msg.source
        self.reward_pub.publish(self.types["f32"](data=float(msg.reward)))
        self.std_pub.publish(self.types["f32"](data=float(msg.reward_std)))
        self.hidden_pub.publish(self.types["array"](data=[float(x) for x in msg.hidden]))


def main(args=None) -> int:
    return VisualizerNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
