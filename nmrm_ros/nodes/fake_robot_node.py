"""fake_robot: a unicycle in a 2 m box that behaves like a robot on ROS 2 (for tests and the docs).

It publishes nav_msgs/Odometry on `odom` and a sensor_msgs/LaserScan of the box's walls on
`scan` (sensor-data QoS, as robots do) `rate` times a second, moves by the latest
geometry_msgs/Twist on `cmd_vel` (linear.x, angular.z; none for `cmd_timeout` s: it stands), and
`~/reset` (std_srvs/Empty) puts it back at the start with a new random heading (seeded by
`seed`). Its dynamics are `nmrm_ros.robots.delivery`'s, so the delivery task's oracle and
`DeliveryEnv` describe what it does; config/robots/fake_delivery.yaml connects it to the graph.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..ros.node_base import NmrmNode
from ..ros.node_main import Param

PARAMETERS = {
    "exit_with_upstream": Param(False, "exit (code 0) once cmd_vel had a publisher and has none left"),
    "rate": Param(20.0, "odometry and scan messages per second (and physics steps)", 0.1),
    "seed": Param(0, "seed of the start headings"),
    "odom_frame": Param("odom", "frame of the odometry (the fixed frame)"),
    "base_frame": Param("base_link", "the robot's frame"),
    "cmd_timeout": Param(0.5, "seconds without a Twist after which the robot stands", 0.0),
    "beams": Param(36, "laser beams round the robot", 1),
}


class FakeRobotNode(NmrmNode):
    executable = "fake_robot"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import LaserScan
        from std_srvs.srv import Empty

        from ..robots import delivery

        self.delivery = delivery
        self.rng = np.random.default_rng(int(p["seed"]))
        self.dt = 1.0 / float(p["rate"])
        self.frames = (str(p["odom_frame"]), str(p["base_frame"]))
        self.cmd_timeout = float(p["cmd_timeout"])
        self.beams = int(p["beams"])
        self.pose = self._start()
        self.cmd = (0.0, 0.0)
        self.cmd_at = 0.0
        self.resets = 0
        self.Odometry, self.LaserScan = Odometry, LaserScan
        self.odom_pub = self.create_publisher(Odometry, "odom", qos_profile_sensor_data)
        self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data)
        sub = self.create_subscription(Twist, "cmd_vel", self.on_cmd, 10)
        self.exit_with_upstream(sub)
        self.create_service(Empty, "~/reset", self.on_reset)
        self.create_timer(self.dt, self.on_tick)
        self.get_logger().info(f"a unicycle in a {delivery.SIZE:g} m box at {p['rate']:g} Hz: odom, scan, "
                               f"cmd_vel, ~/reset")
        self.diagnose(lambda: {"resets": self.resets})

    def _start(self) -> tuple:
        return (*self.delivery.START, float(self.rng.uniform(-math.pi, math.pi)))

    def on_cmd(self, msg) -> None:
        self.cmd = (float(msg.linear.x), float(msg.angular.z))
        self.cmd_at = time.monotonic()

    def on_reset(self, request, response):
        self.pose = self._start()
        self.cmd = (0.0, 0.0)
        self.resets += 1
        return response

    def on_tick(self) -> None:
        v, w = self.cmd if time.monotonic() - self.cmd_at <= self.cmd_timeout else (0.0, 0.0)
        self.pose = self.delivery.step_unicycle(*self.pose, v, w, self.dt)
        x, y, heading = self.pose
        stamp = self.get_clock().now().to_msg()
        odom = self.Odometry()
        odom.header.stamp, odom.header.frame_id = stamp, self.frames[0]
        odom.child_frame_id = self.frames[1]
        odom.pose.pose.position.x, odom.pose.pose.position.y = x, y
        odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(heading / 2), math.cos(heading / 2)
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = v, w
        self.odom_pub.publish(odom)
        scan = self.LaserScan()
        scan.header.stamp, scan.header.frame_id = stamp, self.frames[1]
        scan.angle_min, scan.angle_max = 0.0, 2 * math.pi * (self.beams - 1) / self.beams
        scan.angle_increment = 2 * math.pi / self.beams
        scan.range_min, scan.range_max = 0.0, 3.0
        scan.ranges = [float(r) for r in self.delivery.scan(x, y, heading, self.beams, scan.range_max)]
        self.scan_pub.publish(scan)

    def close(self) -> None:
        self.get_logger().info(f"{self.resets} reset(s)")


def main(args=None) -> int:
    return FakeRobotNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
