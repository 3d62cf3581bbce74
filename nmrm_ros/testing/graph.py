"""Graph tests: start node processes and `nmrm launch`, capture every nmrm topic from this process."""

from __future__ import annotations

import os
import subprocess
import time
import warnings

import numpy as np
import rclpy

from ..ros.ament_paths import node_command, require_share_dir
from ..ros.node_main import TEARDOWN_CUT_EXIT, _executor

from nmrm_msgs.msg import (AgentAction, EnvObservation, OracleStep, RewardStep, TrajectoryPreference,
                            TrajectoryReturn)
from sensor_msgs.msg import CompressedImage

from ..ros.topics import (ACTION, OBSERVATION, OBSERVATION_IMAGE, ORACLE_STEP, REWARD_STEP, STEP_QOS,
                          TRAJECTORY_PREFERENCE, TRAJECTORY_RETURN)

#: episodes from this number on are `Capture.handshake` probes
PROBE_EPISODE = 1000


def executable(name: str) -> str:
    return node_command(name)[0]


def start(name: str, **params) -> subprocess.Popen:
    """Start node executable `name` with ROS parameters, output captured."""
    return subprocess.Popen(node_command(name, **params), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=os.environ.copy())


def launch(*arguments: str) -> subprocess.Popen:
    """`nmrm launch` of the installed graph.launch.yaml with launch arguments, output captured."""
    launch_file = require_share_dir("nmrm_ros") / "launch_scripts" / "graph.launch.yaml"
    return subprocess.Popen([executable("nmrm"), "launch", str(launch_file), *arguments],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=os.environ.copy())


_TOPICS = {"observation": (EnvObservation, OBSERVATION), "action": (AgentAction, ACTION),
           "reward_step": (RewardStep, REWARD_STEP), "label": (TrajectoryReturn, TRAJECTORY_RETURN),
           "oracle_step": (OracleStep, ORACLE_STEP),
           "preference": (TrajectoryPreference, TRAJECTORY_PREFERENCE),
           "observation_image": (CompressedImage, OBSERVATION_IMAGE)}


class Capture:
    """An in-process rclpy node that records every message on the nmrm topics.

    Topics named in `deferred` are subscribed to only by `subscribe_when_matched`: a graph whose
    env_sim waits for this capture's observation subscription then starts only after the capture
    has matched every other node's publisher. Waiting a fixed time is not enough: discovery between
    a process that started earlier (this one) and the graph's nodes can take seconds, and the
    topics are volatile, so a late match loses everything published before it.
    """

    def __init__(self, deferred: tuple = ()) -> None:
        self.deferred = tuple(deferred)
        rclpy.init()
        self.node = rclpy.create_node("test_capture")
        self.msgs: dict = {k: [] for k in _TOPICS}
        self.subs: dict = {}
        for key in _TOPICS:
            if key not in self.deferred:
                self._subscribe(key)
        self.executor = _executor()
        self.executor.add_node(self.node)

    def _subscribe(self, key: str) -> None:
        typ, topic = _TOPICS[key]
        self.subs[key] = self.node.create_subscription(typ, topic, self.msgs[key].append, STEP_QOS)

    def wait_for_publishers(self, publishers: dict, timeout: float = 60.0) -> None:
        """Spin until the capture has matched `publishers[key]` publishers on each topic `key`."""
        def counts():
            return {k: self.subs[k].get_publisher_count() for k in publishers}
        if not self.spin_until(lambda: all(c >= publishers[k] for k, c in counts().items()), timeout):
            raise AssertionError(f"capture matched publishers {counts()}, expected {publishers}")

    def subscribe_when_matched(self, publishers: dict, timeout: float = 60.0) -> None:
        """`wait_for_publishers`, then subscribe to the deferred topics."""
        self.wait_for_publishers(publishers, timeout)
        for key in self.deferred:
            self._subscribe(key)

    def handshake(self, send_probe, topics: tuple, first_episode: int = PROBE_EPISODE,
                  timeout: float = 30.0) -> int:
        """Send probe episodes `first_episode`, +1, ... (`send_probe(episode)` publishes one)
        until a reply to one of them arrived on each of `topics`; returns how many were sent.

        Matching counts say only what this process has matched: a node's publisher may not yet
        have matched the capture's subscription (or its subscription this publisher), and with
        volatile topics whatever it publishes before that is lost to the capture (a CI run lost
        a label so). A reply on each topic proves both directions. Tests ignore the probes'
        episodes (>= first_episode)."""
        deadline = time.monotonic() + timeout
        sent = 0
        def answered():
            return all(any(m.episode >= first_episode for m in self.msgs[t]) for t in topics)
        while time.monotonic() < deadline:
            send_probe(first_episode + sent)
            sent += 1
            if self.spin_until(answered, 1.0):
                return sent
        raise AssertionError(f"no reply on {topics} to {sent} probe episode(s) in {timeout} s")

    def joined(self, key: str, task: str) -> list:
        """The messages captured on `key` ("observation", "reward_step"), on an image task with the
        pixels of the captured observation images put back in front of their states, as a node's
        `subscribe_steps` does (`ros.observation_images.ImagePairing`); on another task as captured."""
        from ..ros.observation_images import ImagePairing
        from ..tasks import task_info

        info = task_info(task)
        if not info.image_shape:
            return list(self.msgs[key])
        out: list = []
        fields = ("state", "augmented_state") if key == "reward_step" else ("state",)
        pairing = ImagePairing(info.image_shape, info.state_size, out.append, fields,
                               capacity=len(self.msgs["observation_image"]) + len(self.msgs[key]) + 1)
        for image in self.msgs["observation_image"]:
            pairing.on_image(image)
        for m in self.msgs[key]:
            pairing.on_message(m)
        assert pairing.bad_images == 0, pairing.last_error
        return out

    def publisher(self, typ, topic):
        return self.node.create_publisher(typ, topic, STEP_QOS)

    def spin_until(self, predicate, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return predicate()

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown()


def finish(proc: subprocess.Popen, timeout: float = 30.0) -> tuple:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        raise AssertionError(f"process did not finish:\n{out}")
    if proc.returncode == TEARDOWN_CUT_EXIT:  # work done, Fast DDS's teardown cut (node_main): clean, said
        warnings.warn(f"a node's DDS teardown was cut after its work was done:\n{out[-2000:]}")
        return 0, out
    return proc.returncode, out


def episodes_of(observations: list) -> dict:
    """episode -> (states (L + 1, d) array in step order, list of steps, final flags)."""
    out: dict = {}
    for m in observations:
        out.setdefault(m.episode, []).append(m)
    return {e: (np.array([list(m.state) for m in ms], np.float32), [m.step for m in ms],
                [(m.terminated, m.truncated) for m in ms]) for e, ms in out.items()}


class OutputLines:
    """The output of a running process, read line by line in a thread: `wait_for(text)` returns
    the `count`-th line containing `text` (or fails with all the output so far)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        import threading

        self.lines: list = []
        self.reader = threading.Thread(target=lambda: self.lines.extend(proc.stdout), daemon=True)
        self.reader.start()

    def wait_for(self, text: str, count: int = 1, timeout: float = 90.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [line for line in list(self.lines) if text in line]
            if len(found) >= count:
                return found[count - 1]
            time.sleep(0.2)
        raise AssertionError(f"no {count} x {text!r} in\n{self.text()}")

    def text(self) -> str:
        return "".join(self.lines)
