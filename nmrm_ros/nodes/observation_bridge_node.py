"""observation_bridge: a robot's standard topics in, the graph's observation stream out.

Reads the `observation:` and `episode:` sections of a robot spec (`spec`, a YAML file;
`nmrm_ros.ros.robot_spec`): it subscribes to each input topic (nav_msgs/Odometry,
geometry_msgs/PoseStamped, sensor_msgs/JointState, sensor_msgs/LaserScan, std_msgs/Float32MultiArray
or any message whose fields are numbers; cameras, sensor_msgs/Image and CompressedImage, resized),
keeps the latest value of each, and `rate` times a second publishes one EnvObservation on
`nmrm/observation`, for `task`: the cameras' pixels then the other fields in order as its state,
the fields of inputs marked privileged as its privileged state. The pixels travel as a PNG on
`nmrm/observation_image` beside the EnvObservation, as env_sim sends an image task's
(`nmrm_ros.ros.observation_images`). A task spec with a frozen encoder
(`encoder=<module>:<attribute>[,encoder_weights=<file>]`, `nmrm_ros.tasks.frozen_encoder`) gets the
encoder's features of the cameras' frame in place of its pixels, as the task's own env would give.
A tick with an input older than `stale_after` s (or never seen) publishes nothing and is counted
(a warning every 5 s says which input); a message whose fields cannot be read (a missing joint, a
NaN) is dropped and counted the same way. Time is the node's clock, so `use_sim_time` is honoured.

Episodes: with `auto_start` (default) one starts at once and the next right after one ends;
else by the `~/start_episode` service (std_srvs/Trigger). An episode ends at `max_steps`
(truncated), when the state leaves the spec's box (terminated), or by `~/end_episode` (truncated,
on the current state). Between episodes the spec's `reset_service` (std_srvs/Empty) is called if
given, and the next episode starts once it answered (or `reset_timeout` s passed: a warning).
`episodes` > 0 stops after that many (the node then exits 0). Everything downstream — reward
model, labellers, recorder, trainer, agent — sees episodes exactly as from env_sim.
"""

from __future__ import annotations

import time

import numpy as np

from nmrm_msgs.msg import EnvObservation

from ..ros.messages import to_float_list
from ..ros.node_base import NmrmNode
from ..ros.node_main import NodeError, Param, require_robot_spec, require_task
from ..ros.topics import ACTION, OBSERVATION, OBSERVATION_IMAGE, STEP_QOS

PARAMETERS = {
    "spec": Param("", "robot spec YAML (observation:, episode:, action: sections; see nmrm_ros.ros.robot_spec)"),
    "task": Param("", "task whose observations these are (its state size must match the spec's fields)"),
    "episodes": Param(0, "stop after this many episodes (0 = for ever)", 0),
    "first_episode": Param(0, "id of the first episode", 0),
    "auto_start": Param(True, "start episodes by themselves (false: by the ~/start_episode service)"),
    "reset_timeout": Param(10.0, "seconds to wait for the reset service between episodes", 0.0),
    "wait_for_subscribers": Param(0, "auto_start: the first episode waits for this many observation subscribers", 0),
    "wait_for_agent": Param(False, "auto_start: the first episode also waits for a publisher of nmrm/action (an agent "
                                   "that is ready to act: a learning agent starts late)"),
    "start_delay": Param(0.0, "seconds to wait once they are there, so late endpoints of other nodes match", 0.0),
}

WARN_EVERY_S = 5.0


class ObservationBridgeNode(NmrmNode):
    executable = "observation_bridge"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        from std_srvs.srv import Empty, Trigger

        from ..ros.field_paths import message_class

        if p["spec"] and not p["task"]:
            raise NodeError("task is required: the task whose observations the robot makes")
        self.spec = require_robot_spec(p["spec"])
        self.info = require_task(p["task"])
        self.task = p["task"]
        self.expected = self.info.state_size
        have = "x".join(map(str, self.spec.image_shape)) or "no camera"
        self.encoder = None  # the task spec's frozen encoder: the cameras' frame -> its features
        if self.info.encoder_image_shape:
            if tuple(self.info.encoder_image_shape) != tuple(self.spec.image_shape):
                want = "x".join(map(str, self.info.encoder_image_shape))
                raise NodeError(f"the spec's cameras make {have}; task {self.task}'s encoder reads {want} "
                                f"(H x W x C: the cameras' image size and channels)")
            from ..tasks.frozen_encoder import EncoderError
            from ..tasks.gym_task import task_encoder

            try:
                self.encoder = task_encoder(self.task, tuple(self.spec.image_shape))
            except EncoderError as exc:
                raise NodeError(str(exc)) from None
        elif tuple(self.info.image_shape) != tuple(self.spec.image_shape):
            want = "x".join(map(str, self.info.image_shape)) or "no image"
            raise NodeError(f"the spec's cameras make {have}; task {self.task} has {want} in its state "
                            f"(image_shape H x W x C: the cameras' image size and channels)")
        self.episodes = int(p["episodes"])
        self.auto_start = bool(p["auto_start"])
        self.reset_timeout = float(p["reset_timeout"])
        self.latest: list = [None] * len(self.spec.inputs)  # (values, receive time in ns)
        self.dropped = [0] * len(self.spec.inputs)
        self.stale_ticks = 0
        self.encoder_failures = 0
        self.warned_at = 0.0
        self.episode = int(p["first_episode"]) - 1
        self.done_episodes = 0
        self.step = 0
        self.running = False
        self.resetting_since = None
        self.reset_future = None
        self.wrong_size_warned = False  # the state size is checked on the first full sample
        self.privileged_size_warned = False
        self.wait_for = int(p["wait_for_subscribers"])
        self.wait_for_agent = bool(p["wait_for_agent"])
        self.action_topic = self.resolve_topic_name(ACTION)
        self.start_delay = float(p["start_delay"])
        self.ready_at = None  # auto_start: when the subscribers were there
        self.pub = self.create_publisher(EnvObservation, OBSERVATION, STEP_QOS)
        self.images = None  # without a frozen encoder, the cameras' pixels as observation images
        if self.info.image_shape:
            from ..ros.observation_images import ObservationImagePublisher

            self.images = ObservationImagePublisher(self, self.info, OBSERVATION_IMAGE)
        for i, inp in enumerate(self.spec.inputs):
            self.create_subscription(message_class(inp.type_name), inp.topic,
                                     lambda msg, i=i: self.on_input(i, msg), _qos(inp.qos))
        self.create_service(Trigger, "~/start_episode", self.on_start)
        self.create_service(Trigger, "~/end_episode", self.on_end)
        self.reset_client = self.create_client(Empty, self.spec.reset_service) if self.spec.reset_service else None
        self.create_timer(1.0 / self.spec.rate, self.on_tick)
        self.get_logger().info(
            f"task {self.task}: {len(self.spec.inputs)} input(s) "
            f"({', '.join(i.topic for i in self.spec.inputs)}) at {self.spec.rate:g} Hz, stale after "
            f"{self.spec.stale_after:g} s; episodes {'start by themselves' if self.auto_start else 'by ~/start_episode'}"
            f", end at {self.spec.max_steps or 'no'} step limit{', leaving the box' if self.spec.box_dims else ''}"
            f", by ~/end_episode")
        self.waiting = self.auto_start  # the first episode starts once the subscribers are there

        self.diagnose(lambda: {"episode": self.episode, "stale_ticks": self.stale_ticks,
                               "encoder_failures": self.encoder_failures,
            **{f"dropped {i.topic}": n for i, n in zip(self.spec.inputs, self.dropped)}},
            warn=lambda: "; ".join(w for w in (f"{self.stale_ticks} stale tick(s)" if self.stale_ticks else "",
                                               f"{self.encoder_failures} tick(s) the encoder failed on"
                                               if self.encoder_failures else "") if w) or None)

    # -- inputs ------------------------------------------------------------------------------------
    def on_input(self, i: int, msg) -> None:
        try:
            values = self.spec.inputs[i].read(msg)
        except ValueError as exc:
            self.dropped[i] += 1
            self._warn(f"{self.spec.inputs[i].topic}: message dropped ({self.dropped[i]} so far): {exc}")
            return
        self.latest[i] = (values, self.get_clock().now().nanoseconds)

    def _warn(self, text: str) -> None:
        now = time.monotonic()
        if now - self.warned_at >= WARN_EVERY_S:
            self.warned_at = now
            self.get_logger().warning(text)

    def sample(self) -> tuple | None:
        """(state, privileged state) of now (the latest value of every input: the cameras' pixels
        stacked along C, then the other fields; the privileged inputs' fields), or None if an
        input is stale or missing."""
        now = self.get_clock().now().nanoseconds
        images, state, privileged = [], [], []
        for inp, got in zip(self.spec.inputs, self.latest):
            if got is None or (now - got[1]) / 1e9 > self.spec.stale_after:
                self.stale_ticks += 1
                age = "never received" if got is None else f"{(now - got[1]) / 1e9:.2f} s old"
                self._warn(f"{inp.topic} is stale ({age}); {self.stale_ticks} tick(s) skipped so far")
                return None
            if inp.image is not None:
                images.append(got[0])
            elif inp.privileged:
                privileged += got[0]
            else:
                state += got[0]
        if images:
            image = np.concatenate(images, axis=2)
            if self.encoder is not None:
                from ..tasks.frozen_encoder import EncoderError

                try:
                    image = self.encoder(image)
                except EncoderError as exc:  # it failed on this frame, or gave NaN: the tick is skipped
                    self.encoder_failures += 1
                    self._warn(f"{exc}; {self.encoder_failures} tick(s) skipped so far")
                    return None
            state = image.reshape(-1).tolist() + state
        if len(state) != self.expected:
            if not self.wrong_size_warned:
                self.get_logger().error(f"the spec's inputs make {len(state)} state values, task {self.task} has "
                                        f"state size {self.expected}: nothing published")
                self.wrong_size_warned = True
            return None
        wanted = self.info.privileged_size
        if wanted and privileged and len(privileged) != wanted and not self.privileged_size_warned:
            self.get_logger().error(f"the spec's privileged inputs make {len(privileged)} values, task {self.task}'s "
                                    f"oracle takes {wanted}")
            self.privileged_size_warned = True
        return state, privileged

    # -- episodes ----------------------------------------------------------------------------------
    def begin(self) -> None:
        self.episode += 1
        self.step = 0
        self.running = True

    def finish_episode(self, sample: tuple, terminated: bool, truncated: bool) -> None:
        self.publish(sample, terminated, truncated)
        self.running = False
        self.done_episodes += 1
        self.get_logger().info(f"episode {self.episode}: {self.step} steps, "
                               f"{'left the box' if terminated else 'truncated'}")
        if self.episodes and self.done_episodes >= self.episodes:
            self.exit_code = 0
            return
        if self.reset_client is not None:
            from std_srvs.srv import Empty

            self.resetting_since = time.monotonic()
            self.reset_future = self.reset_client.call_async(Empty.Request()) if self.reset_client.service_is_ready() else None
        elif self.auto_start:
            self.begin()

    def publish(self, sample: tuple, terminated: bool = False, truncated: bool = False) -> None:
        state, privileged = sample
        stamp = self.get_clock().now().to_msg()
        if self.images is not None:
            state = self.images.publish(np.asarray(state), self.episode, self.step, stamp)
        msg = EnvObservation(task=self.task, episode=self.episode, step=self.step, state=to_float_list(state),
                             privileged=to_float_list(privileged), terminated=terminated, truncated=truncated)
        msg.header.stamp = stamp
        msg.header.frame_id = self.task
        self.pub.publish(msg)

    def on_tick(self) -> None:
        if self.waiting:
            if self.pub.get_subscription_count() < self.wait_for or (
                    self.images is not None and self.images.pub.get_subscription_count() < self.wait_for):
                return
            if self.wait_for_agent and self.count_publishers(self.action_topic) < 1:
                return
            self.ready_at = self.ready_at or time.monotonic()
            if time.monotonic() - self.ready_at < self.start_delay:
                return
            self.waiting = False
            self.begin()
        if self.resetting_since is not None:
            answered = self.reset_future is not None and self.reset_future.done()
            if answered or time.monotonic() - self.resetting_since > self.reset_timeout:
                if not answered:
                    self.get_logger().warning(f"{self.spec.reset_service} did not answer in {self.reset_timeout:g} s")
                self.resetting_since = self.reset_future = None
                if self.auto_start:
                    self.begin()
            return
        if not self.running:
            return
        sample = self.sample()
        if sample is None:
            return
        if self.spec.max_steps and self.step >= self.spec.max_steps:
            self.finish_episode(sample, False, True)
        elif self.step > 0 and self.spec.left_box(sample[0]):
            self.finish_episode(sample, True, False)
        else:
            self.publish(sample)
            self.step += 1

    def on_start(self, request, response):
        if self.running:
            response.success, response.message = False, f"episode {self.episode} is running"
        elif self.resetting_since is not None:
            response.success, response.message = False, "resetting the robot"
        elif self.exit_code is not None:
            response.success, response.message = False, "all episodes done"
        else:
            self.waiting = False
            self.begin()
            response.success, response.message = True, f"episode {self.episode} started"
        return response

    def on_end(self, request, response):
        if not self.running or self.step == 0:
            response.success, response.message = False, "no episode with a step to end"
            return response
        sample = self.sample()
        if sample is None:
            response.success, response.message = False, "an input is stale: cannot publish the final observation"
            return response
        ended = self.episode
        self.finish_episode(sample, False, True)
        response.success, response.message = True, f"episode {ended} ended at step {self.step}"
        return response

    def close(self) -> None:
        self.get_logger().info(f"{self.done_episodes} episode(s); {self.stale_ticks} stale tick(s); dropped "
                               + ", ".join(f"{i.topic} {d}" for i, d in zip(self.spec.inputs, self.dropped)))


def _qos(name: str):
    from rclpy.qos import qos_profile_sensor_data

    return qos_profile_sensor_data if name == "sensor_data" else STEP_QOS


def main(args=None) -> int:
    return ObservationBridgeNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
