"""Test helper process: publish N EnvObservation messages on a topic once a subscriber is matched.

Usage: observation_publisher.py TOPIC N
"""

import sys
import time

import rclpy
from nmrm_msgs.msg import EnvObservation
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy


def main() -> int:
    topic, n = sys.argv[1], int(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("observation_publisher")
    qos = QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
    pub = node.create_publisher(EnvObservation, topic, qos)
    deadline = time.monotonic() + 30.0
    while pub.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            print("no subscriber matched", file=sys.stderr)
            return 2
        rclpy.spin_once(node, timeout_sec=0.05)
    for i in range(n):
        msg = EnvObservation(task="key", episode=7, step=i, state=[0.01 * i, 1.0 - 0.01 * i])
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.truncated = i == n - 1
        pub.publish(msg)
    # Stay up until the subscriber has gone (it exits after receiving everything).
    deadline = time.monotonic() + 30.0
    while pub.get_subscription_count() > 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
