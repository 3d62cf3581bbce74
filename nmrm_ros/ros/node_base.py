"""`NmrmNode`: the base class of every node of the package — the protocol `run_node` drives.

    class FakeRobotNode(NmrmNode):
        executable = "fake_robot"          # `ros2 run nmrm_ros fake_robot`, and the node's name
        PARAMETERS = PARAMETERS            # name -> Param(default, description[, minimum])

        def __init__(self) -> None:
            super().__init__()             # declares PARAMETERS (checked): self.params
            sub = self.create_subscription(Twist, "cmd_vel", self.on_cmd, 10)
            self.exit_with_upstream(sub)   # if the parameter exit_with_upstream is set
            self.diagnose(lambda: {"resets": self.resets})   # /diagnostics

        def close(self) -> None: ...       # files complete: called once at shutdown

    def main(args=None) -> int:
        return FakeRobotNode.main(args)    # the executable's entry point

A node ends the process by setting `self.exit_code` (the spin loop stops after the current callback, then
`close()`, flush and teardown: `node_main.run_node`); a `NodeError` raised in `__init__` is a
one-line error and exit code 2. The executable's --help is the module docstring's first line and
the parameter table.
"""

from __future__ import annotations

import sys
from typing import Callable

from rclpy.node import Node

from .node_main import declare_parameters, exit_with_upstream, run_node


class NmrmNode(Node):
    """An rclpy node with the package's protocol: checked parameters, exit code, diagnostics,
    leaving with its upstream, close, main."""

    #: the executable's name (`ros2 run nmrm_ros <executable>`), also the node's default name
    executable: str = ""
    #: name -> Param of the node's ROS parameters
    PARAMETERS: dict = {}
    #: messages taken from the input topic(s) (counts a producer seen by `exit_with_upstream`)
    messages_received: int = 0
    #: on Ctrl-C / SIGTERM, keep taking the messages DDS has already received (and acknowledged to
    #: their publishers) for at most this many seconds before `close()`: 0 = drop them
    drain_on_stop: float = 0.0

    def __init__(self, node_name: str | None = None, **kwargs) -> None:
        #: None while running; set it to end the process with that code (after the current callback)
        self.exit_code: int | None = None
        self.diagnostics = None
        #: the `ImagePairing`s of `subscribe_steps` (their counts: images refused, messages unpaired)
        self.image_pairings: list = []
        super().__init__(node_name or self.executable, **kwargs)
        #: the declared parameters' values (name -> value), checked against their Params
        self.params: dict = declare_parameters(self, self.PARAMETERS)

    def exit_with_upstream(self, subscriptions, on_gone: Callable | None = None) -> None:
        """If the parameter `exit_with_upstream` is set: end (code 0) when `subscriptions` had
        publishers and have none left, or call `on_gone()` then (`node_main.exit_with_upstream`)."""
        if self.params.get("exit_with_upstream"):
            exit_with_upstream(self, subscriptions, on_gone=on_gone)

    def subscribe_steps(self, msg_type, topic: str, callback: Callable, info, fields: tuple = ("state",)) -> list:
        """The subscriptions that give `callback` each message of `topic` (EnvObservation,
        RewardStep); on an image task (`info.image_shape`) with the pixels of its observation
        image (`topics.observation_image_topic(topic)`) put back in front of `fields`
        (`ros.observation_images`; an image refused is a warning line, at most one per 10 s)."""
        from .topics import STEP_QOS, observation_image_topic

        if not info.image_shape:
            return [self.create_subscription(msg_type, topic, callback, STEP_QOS)]
        from sensor_msgs.msg import CompressedImage

        from .observation_images import ImagePairing

        def refused(why: str) -> None:
            self.get_logger().warning(f"observation image refused ({pairing.bad_images} so far): {why}",
                                      throttle_duration_sec=10.0)

        pairing = ImagePairing(info.image_shape, info.state_size, callback, fields, on_error=refused)
        self.image_pairings.append(pairing)
        return [self.create_subscription(msg_type, topic, pairing.on_message, STEP_QOS),
                self.create_subscription(CompressedImage, observation_image_topic(topic), pairing.on_image, STEP_QOS)]

    def tell_starter(self, text: str) -> None:
        """Say `text` (e.g. a URL with an access token) to the person who started the node only:
        on its terminal (stderr, as the logger's INFO lines look), not on /rosout, which anyone on
        the DDS network can read, nor in the ROS log files."""
        print(f"[INFO] [{self.get_name()}]: {text}", file=sys.stderr, flush=True)

    def diagnose(self, values: Callable[[], dict], **kwargs) -> None:
        """Publish `values()` (and rate_of / warn / hardware_id: `ros.diagnostics.Diagnostics`)
        on /diagnostics."""
        from .diagnostics import Diagnostics

        self.diagnostics = Diagnostics(self, values, **kwargs)

    def close(self) -> None:
        """Release the node's files and children (called once at shutdown, before teardown)."""

    @classmethod
    def main(cls, args: list | None = None) -> int:
        """Run the node as its executable until it finishes or is stopped; the exit code."""
        doc = (sys.modules[cls.__module__].__doc__ or cls.executable).strip().splitlines()[0]
        return run_node(cls, cls.executable, doc, cls.PARAMETERS, args)
