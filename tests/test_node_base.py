"""Every node executable is an `NmrmNode`: one protocol (parameters, exit code, diagnostics,
leaving with its upstream, close, main), no node of its own making."""

import importlib
import re
from pathlib import Path

import pytest

from nmrm_ros.ros.node_base import NmrmNode

SETUP = (Path(__file__).resolve().parents[1] / "setup.py").read_text()
EXECUTABLES = dict(re.findall(r'"(\w+)": "(nmrm_ros\.nodes\.\w+):main"', SETUP))


def test_every_node_module_is_an_executable():
    modules = {p.stem for p in (Path(__file__).resolve().parents[1] / "nmrm_ros" / "nodes").glob("*_node.py")}
    assert {m.rsplit(".", 1)[1] for m in EXECUTABLES.values()} == modules


@pytest.mark.parametrize("executable", sorted(EXECUTABLES))
def test_node_class_follows_the_protocol(executable):
    module = importlib.import_module(EXECUTABLES[executable])
    nodes = [v for v in vars(module).values()
             if isinstance(v, type) and issubclass(v, NmrmNode) and v is not NmrmNode and v.__module__ == module.__name__]
    assert len(nodes) == 1, f"{module.__name__}: one NmrmNode per file"
    node = nodes[0]
    assert node.executable == executable
    assert node.PARAMETERS is module.PARAMETERS
    # the parameter that the base class's exit_with_upstream reads is declared wherever it is used
    source = Path(module.__file__).read_text()
    if "self.exit_with_upstream(" in source:
        assert "exit_with_upstream" in node.PARAMETERS
    assert "run_node(" not in source and "getattr(node" not in source


def test_a_node_behind_its_producers_reads_its_backlog_before_it_leaves_with_them(ros_domain):
    """exit_with_upstream with real rclpy: 20 messages reach a node's subscription (acknowledged by
    its reader) while the node is not spinning, and then their publisher leaves. When it spins
    again it reads them slowly (20 ms each: 2 check periods), and its check timer runs between
    them and sees no publishers: the node must read all 20 before it leaves (CI lost a robot's last
    steps when a recorder that was behind left on seeing no publishers)."""
    import time

    import rclpy
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Int32

    from nmrm_ros.ros.node_main import exit_with_upstream
    from nmrm_ros.ros.topics import STEP_QOS

    rclpy.init()
    try:
        consumer, producer = rclpy.create_node("behind"), rclpy.create_node("producer")
        consumer.exit_code, consumer.messages_received, read = None, 0, []

        def on_message(msg):  # a slow consumer: the backlog takes 2 check periods to read
            time.sleep(0.02)
            consumer.messages_received += 1
            read.append(msg.data)

        sub = consumer.create_subscription(Int32, "backlog", on_message, STEP_QOS)
        exit_with_upstream(consumer, sub, period=0.2)
        pub = producer.create_publisher(Int32, "backlog", STEP_QOS)
        executor = SingleThreadedExecutor()
        executor.add_node(consumer)
        executor.add_node(producer)
        deadline = time.monotonic() + 30
        while sub.get_publisher_count() < 1 or pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.05)
        executor.remove_node(consumer)  # from here on the consumer reads nothing until it spins again
        for i in range(20):
            pub.publish(Int32(data=i))
        assert pub.wait_for_all_acked(Duration(seconds=30))
        producer.destroy_publisher(pub)
        executor.spin_once(timeout_sec=0.1)  # the producer's side of the destruction
        while sub.get_publisher_count() > 0:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(0.5)  # the check timer is overdue: it is ready beside the 20 queued messages
        executor.remove_node(producer)
        executor.add_node(consumer)
        while consumer.exit_code is None:
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.05)
        assert read == list(range(20)) and consumer.exit_code == 0
        executor.shutdown()
        consumer.destroy_node()
        producer.destroy_node()
    finally:
        rclpy.shutdown()
