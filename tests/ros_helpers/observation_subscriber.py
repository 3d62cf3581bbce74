"""Test helper process: receive N EnvObservation messages and print them as JSON lines.

Usage: observation_subscriber.py TOPIC N
"""

import json
import sys
import time

import rclpy
from nmrm_msgs.msg import EnvObservation
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy


def main() -> int:
    topic, n = sys.argv[1], int(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("observation_subscriber")
    got = []
    qos = QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
    node.create_subscription(EnvObservation, topic, got.append, qos)
    deadline = time.monotonic() + 30.0
    while len(got) < n and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    for m in got:
        print(json.dumps({"task": m.task, "episode": m.episode, "step": m.step,
                          "state": list(m.state), "truncated": m.truncated}))
    node.destroy_node()
    rclpy.shutdown()
    return 0 if len(got) == n else 1


if __name__ == "__main__":
    sys.exit(main())
