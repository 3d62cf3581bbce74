"""env_sim: owns one task environment and runs its episodes in lock-step with the agent.

Protocol (per episode e, from step t = 0):
  publish EnvObservation(e, t, s_t) -> wait for AgentAction(e, t) -> step -> publish (e, t + 1) ...
At the end of an episode (terminated or truncated) the final observation is published with its
flag set and no action is awaited; the next episode starts. After `episodes` episodes (0 = run
for ever) the node exits with code 0.

Actions for anything but the awaited (episode, step), of the wrong size, NaN/inf, or outside the
action space are dropped with a counted warning, never stepped. If no valid action arrives within
`action_timeout` s the observation is published again (the agent re-sends the same action for a
repeated observation); after `max_retries` repeats the episode is **abandoned** (counted, with the
step it stopped at) and the next one starts at step 0 — the point where every consumer that broke
off (a bad message, a restarted node) joins again. That first observation is re-published every
`action_timeout` s for up to `startup_timeout` s, so a node that is still restarting joins it.
An episode starts only when every node of `wait_for_nodes` subscribes (a killed labeller leaves
the graph within the Fast DDS lease, 5 s with config/fastdds_discovery.xml; env_sim then waits
for it to come back, up to `startup_timeout` s, before the next episode). With `wait_for_labels`
(config/graph.yaml: on, for the oracle labeller) the next episode also waits, up to
`action_timeout` s, for this episode's TrajectoryReturn, so a killed labeller costs the episode in
progress, not every episode run while it restarts. After `max_abandoned` abandoned episodes in a
row the node gives up and exits with code 1. Abandoned episodes count towards `episodes`.
With `render`, each `render_every`-th step's `env.render()` (and the final one) is published on
`nmrm/frame` as a sensor_msgs/CompressedImage (JPEG or PNG, at most `render_width` pixels wide;
header.frame_id names its episode and step: `nmrm_ros.tasks.frames`), so bags and the labelling
page have what a person can watch.
On an image task (`TaskInfo.image_shape`) the state's pixels go out as a lossless PNG
sensor_msgs/CompressedImage on `nmrm/observation_image` just before each EnvObservation (header
as the frames': `nmrm_ros.tasks.image_states`), and the EnvObservation carries the rest of the
state; the consumers join them (`NmrmNode.subscribe_steps`). The observation image's
subscriptions must match too before the first episode.
Before the first episode the node waits until at least `wait_for_subscribers` subscriptions, among
them those of every node named in `wait_for_nodes`, match its observation topic and an action
publisher is matched (up to `startup_timeout` s), then `start_delay` s more (time for the other
nodes' endpoints, e.g. a viewer of the reward topic, to match each other).
"""

from __future__ import annotations

import time

import numpy as np

from nmrm_msgs.msg import AgentAction, EnvObservation, TrajectoryReturn

from ..ros.messages import as_vector, to_float_list
from ..ros.node_base import NmrmNode
from ..ros.node_main import NodeError, Param, require_task, subscribed_nodes
from ..ros.topics import ACTION, FRAME, OBSERVATION, OBSERVATION_IMAGE, STEP_QOS, TRAJECTORY_RETURN

PARAMETERS = {
    "task": Param("key", "timer | moving | key | charger | lunar_lander, or gym:<id> | <module>:<attribute>"),
    "seed": Param(0, "seed of episode 0; episode e resets with seed + e"),
    "episodes": Param(1, "number of episodes to run, 0 = for ever", 0),
    "first_episode": Param(0, "id of the first episode (ids key labels: give each session its own range)", 0),
    "continuous": Param(False, "continuous-action variant of the navigation tasks"),
    "action_timeout": Param(5.0, "seconds to wait for an action before re-publishing the observation", 0.001),
    "max_retries": Param(3, "re-publications of one observation before abandoning the episode", 0),
    "max_abandoned": Param(5, "abandoned episodes in a row before giving up (exit 1)", 1),
    "wait_for_labels": Param(False, "before the next episode, wait up to action_timeout for this one's "
                                    "TrajectoryReturn (an oracle labeller in the loop; not for people)"),
    "wait_for_subscribers": Param(1, "observation subscriptions to wait for before starting", 0),
    "wait_for_nodes": Param([""], "names of nodes whose observation subscriptions to wait for"),
    "startup_timeout": Param(60.0, "seconds to wait for subscribers and an action publisher", 0.001),
    "start_delay": Param(0.0, "seconds to wait once ready, so late endpoints of other nodes match", 0.0),
    "render": Param(False, "publish env.render() frames on nmrm/frame (sensor_msgs/CompressedImage)"),
    "render_every": Param(1, "render: a frame every this many steps (the final step always)", 1),
    "render_width": Param(240, "render: frames scaled down to at most this many pixels wide", 16),
    "render_format": Param("jpeg", "render: jpeg | png"),
    "render_quality": Param(75, "render: JPEG quality, 1..95", 1),
}


class EnvSimNode(NmrmNode):
    executable = "env_sim"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        from ..tasks import make_env
        from ..tasks.frames import FRAME_FORMATS

        self.info = require_task(p["task"])
        self.task = p["task"]
        self.render = bool(p["render"])
        if p["render_format"] not in FRAME_FORMATS:
            raise NodeError(f"render_format must be one of {', '.join(FRAME_FORMATS)}, got {p['render_format']!r}")
        if not 1 <= p["render_quality"] <= 95:
            raise NodeError(f"render_quality must be in 1..95, got {p['render_quality']}")
        self.frame_settings = (int(p["render_width"]), p["render_format"], int(p["render_quality"]))
        self.render_every = int(p["render_every"])
        try:
            self.env = make_env(self.task, continuous=p["continuous"], render=self.render)
        except ValueError as exc:
            raise NodeError(str(exc)) from None
        self.frames_sent = self.frame_bytes = 0
        self.framed = None  # (episode, step) of the last frame published
        self.discrete = self.info.discrete and not p["continuous"]
        self.seed = int(p["seed"])
        self.episodes = int(p["episodes"])
        self.first_episode = int(p["first_episode"])
        self.action_timeout = float(p["action_timeout"])
        self.max_retries = int(p["max_retries"])
        self.max_abandoned = int(p["max_abandoned"])
        self.abandoned = 0  # episodes abandoned in all
        self.abandoned_in_a_row = 0
        self.abandoned_at = 0.0
        self.waiting_since = None  # monotonic time since a node of wait_for_nodes is missing
        self.startup_timeout = float(p["startup_timeout"])
        self.wait_for = int(p["wait_for_subscribers"])
        self.wait_for_nodes = {n for n in p["wait_for_nodes"] if n}
        self.startup_deadline = time.monotonic() + float(p["startup_timeout"])
        self.start_delay = float(p["start_delay"])
        self.ready_at = None

        self.pub = self.create_publisher(EnvObservation, OBSERVATION, STEP_QOS)
        self.images = None  # an image task's observation images
        if self.info.image_shape:
            from ..ros.observation_images import ObservationImagePublisher

            self.images = ObservationImagePublisher(self, self.info, OBSERVATION_IMAGE)
        if self.render:
            from sensor_msgs.msg import CompressedImage

            self.frame_pub = self.create_publisher(CompressedImage, FRAME, STEP_QOS)
        self.sub = self.create_subscription(AgentAction, ACTION, self.on_action, STEP_QOS)
        self.wait_for_labels = bool(p["wait_for_labels"])
        self.awaiting_label = None  # (episode, since) while waiting for an episode's label
        self.unlabelled = 0
        if self.wait_for_labels:
            self.labels_sub = self.create_subscription(TrajectoryReturn, TRAJECTORY_RETURN, self.on_label,
                                                       STEP_QOS)
        self.episode = self.first_episode - 1
        self.step_index = 0
        self.state = None
        self.privileged = ()  # the current step's privileged state (info["privileged"]; empty: none)
        self.retries = 0
        self.sent_at = 0.0
        self.dropped = 0
        self.steps_total = 0
        self.started = False
        self.timer = self.create_timer(0.05, self.on_timer)
        self.get_logger().info(f"task {self.task}, seed {self.seed}, episodes {self.episodes or 'forever'}; "
                               f"waiting for {self.wait_for} subscriber(s) "
                               f"{sorted(self.wait_for_nodes) or ''}")

        self.diagnose(lambda: {"episode": self.episode, "steps": self.steps_total, "abandoned_episodes": self.abandoned,
            "dropped_actions": self.dropped}, rate_of="steps", hardware_id=self.task,
            warn=lambda: f"{self.abandoned_in_a_row} episode(s) abandoned in a row" if self.abandoned_in_a_row else None)

    # -- lifecycle -----------------------------------------------------------------------------
    def on_timer(self) -> None:
        now = time.monotonic()
        if not self.started:
            ready = (self.pub.get_subscription_count() >= self.wait_for
                     and (self.images is None or self.images.pub.get_subscription_count() >= self.wait_for)
                     and self.sub.get_publisher_count() >= 1
                     and not self.missing_nodes())
            if ready and self.ready_at is None:
                self.ready_at = now
            if self.ready_at is not None and now - self.ready_at >= self.start_delay:
                self.started = True
                self.t_start = now
                self.start_episode()
            elif self.ready_at is None and now > self.startup_deadline:
                missing = self.missing_nodes()
                self.get_logger().error(
                    f"start-up timeout: {self.pub.get_subscription_count()} observation subscriber(s) "
                    f"of {self.wait_for}, missing nodes {sorted(missing)}, "
                    f"{self.sub.get_publisher_count()} action publisher(s)")
                self.exit_code = 1
            return
        if self.awaiting_label is not None:
            episode, since = self.awaiting_label
            if now - since > self.action_timeout:
                self.unlabelled += 1
                self.awaiting_label = None
                self.get_logger().warning(f"no label for episode {episode} within {self.action_timeout} s "
                                          f"({self.unlabelled} so far); starting the next episode")
                self.start_episode()
            return
        if self.waiting_since is not None:
            missing = self.missing_nodes()
            if not missing:
                self.get_logger().info(f"all of {sorted(self.wait_for_nodes)} are back; episode {self.episode} starts")
                self.begin_episode()
            elif now - self.waiting_since > self.startup_timeout:
                self.get_logger().error(f"{sorted(missing)} did not come back within {self.startup_timeout:.0f} s; "
                                        f"giving up before episode {self.episode}")
                self.exit_code = 1
            return
        if self.state is not None and now - self.sent_at > self.action_timeout:
            rejoining = (self.step_index == 0 and self.abandoned_in_a_row > 0
                         and now - self.abandoned_at < self.startup_timeout)
            if self.retries >= self.max_retries and not rejoining:
                self.abandon_episode()
                return
            self.retries += 1
            self.get_logger().warning(
                f"action timeout at episode {self.episode} step {self.step_index}; re-publishing the "
                + (f"observation ({self.retries}/{self.max_retries})" if not rejoining else
                   f"first observation after an abandoned episode, for a restarted node to join "
                   f"(up to startup_timeout, {now - self.abandoned_at:.0f}/{self.startup_timeout:.0f} s)"))
            self.publish_observation(False, False)

    def missing_nodes(self) -> set:
        """Nodes of `wait_for_nodes` without an observation subscription right now."""
        return self.wait_for_nodes - subscribed_nodes(self, self.pub.topic_name)

    def abandon_episode(self) -> None:
        """No valid action after `max_retries` re-publications: count the episode as abandoned and
        start the next one (or give up after `max_abandoned` in a row)."""
        self.abandoned += 1
        self.abandoned_in_a_row += 1
        self.abandoned_at = time.monotonic()
        self.retries = 0
        if self.abandoned_in_a_row >= self.max_abandoned:
            self.get_logger().error(f"no valid action for episode {self.episode} step {self.step_index}; "
                                    f"{self.abandoned_in_a_row} episodes abandoned in a row; giving up")
            self.state = None
            self.exit_code = 1
            return
        self.get_logger().warning(f"episode {self.episode} abandoned at step {self.step_index}: no valid "
                                  f"action after {self.max_retries} re-publications ({self.abandoned} "
                                  f"abandoned so far); starting the next episode")
        self.start_episode()

    def start_episode(self) -> None:
        self.episode += 1
        if self.episodes and self.episode - self.first_episode >= self.episodes:
            seconds = time.monotonic() - self.t_start
            self.get_logger().info(f"done: {self.episode - self.first_episode} episodes, {self.steps_total} steps in "
                                   f"{seconds:.2f} s ({self.steps_total / max(seconds, 1e-9):.0f} steps/s), "
                                   f"{self.dropped} action(s) dropped, {self.abandoned} episode(s) "
                                   f"abandoned (no valid action after {self.max_retries} re-publications)"
                                   + (f", {self.unlabelled} without a label" if self.wait_for_labels else "")
                                   + (f"; {self.frames_sent} frame(s), {self.frame_bytes / 1e6:.2f} MB"
                                      if self.render else ""))
            self.state = None
            self.exit_code = 0
            return
        missing = self.missing_nodes()
        if missing:  # a node of wait_for_nodes left (killed): wait for it to come back
            self.get_logger().warning(f"{sorted(missing)} left the graph; episode {self.episode} waits for "
                                      f"them (up to startup_timeout, {self.startup_timeout:.0f} s)")
            self.state = None
            self.waiting_since = time.monotonic()
            return
        self.begin_episode()

    def begin_episode(self) -> None:
        self.waiting_since = None
        obs, info = self.env.reset(seed=self.seed + self.episode)
        self.step_index = 0
        self.state = obs
        self.privileged = info.get("privileged", ())
        self.publish_observation(False, False)

    def publish_observation(self, terminated: bool, truncated: bool) -> None:
        state, stamp = self.state, self.get_clock().now().to_msg()
        if self.images is not None:  # the pixels as an image, the rest in the observation
            state = self.images.publish(state, self.episode, self.step_index, stamp)
        msg = EnvObservation(task=self.task, episode=self.episode, step=self.step_index,
                             state=to_float_list(state), terminated=terminated, truncated=truncated,
                             privileged=to_float_list(self.privileged))
        msg.header.stamp = stamp
        msg.header.frame_id = self.task
        self.sent_at = time.monotonic()
        self.pub.publish(msg)
        final = terminated or truncated
        if self.render and (self.step_index % self.render_every == 0 or final) \
                and self.framed != (self.episode, self.step_index):  # not again on a re-publication
            self.publish_frame(msg.header.stamp)

    def publish_frame(self, stamp) -> None:
        """The frame of the current step on nmrm/frame (nmrm_ros.tasks.frames); a render that
        fails is an error line, never a crash (the episode goes on without its frame)."""
        from sensor_msgs.msg import CompressedImage

        from ..tasks.frames import encode_frame, frame_id

        self.framed = (self.episode, self.step_index)
        width, fmt, quality = self.frame_settings
        try:
            data = encode_frame(self.env.render(), width, fmt, quality)
        except Exception as exc:  # noqa: BLE001 - the user's env: one line, no frame
            self.get_logger().error(f"episode {self.episode} step {self.step_index}: no frame: "
                                    f"render() failed: {type(exc).__name__}: {exc}")
            return
        out = CompressedImage(format=fmt, data=data)
        out.header.stamp = stamp
        out.header.frame_id = frame_id(self.episode, self.step_index)
        self.frame_pub.publish(out)
        self.frames_sent += 1
        self.frame_bytes += len(data)

    # -- actions -------------------------------------------------------------------------------
    def drop(self, why: str) -> None:
        self.dropped += 1
        self.get_logger().warning(f"dropped action ({self.dropped} so far): {why}")

    def on_action(self, msg: AgentAction) -> None:
        if self.state is None or msg.episode != self.episode or msg.step != self.step_index:
            # stale (answer to an old or re-published observation) or from the future
            if not (msg.episode == self.episode and msg.step < self.step_index):
                self.drop(f"for episode {msg.episode} step {msg.step}, awaiting episode "
                          f"{self.episode} step {self.step_index}")
            else:
                self.dropped += 1  # a duplicate answer to a re-published observation: expected
            return
        try:
            action = self.parse_action(msg.action)
        except ValueError as exc:
            self.drop(str(exc))
            return
        obs, _, terminated, truncated, info = self.env.step(action)
        self.steps_total += 1
        self.retries = 0
        self.step_index += 1
        self.state = obs
        self.privileged = info.get("privileged", ())
        if terminated or truncated:
            self.publish_observation(bool(terminated), bool(truncated))
            self.abandoned_in_a_row = 0
            self.state = None
            if self.wait_for_labels:
                self.awaiting_label = (self.episode, time.monotonic())
            else:
                self.start_episode()
        else:
            self.publish_observation(False, False)

    def on_label(self, msg: TrajectoryReturn) -> None:
        if self.awaiting_label is not None and msg.episode == self.awaiting_label[0]:
            self.awaiting_label = None
            self.start_episode()

    def parse_action(self, values) -> np.ndarray | int:
        if self.discrete:
            a = as_vector(values, 1, "action")[0]
            if a != int(a) or not 0 <= a < self.info.action_size:
                raise ValueError(f"discrete action {a} is not an index in 0..{self.info.action_size - 1}")
            return int(a)
        size = 2 if self.info.navigation else self.info.action_size  # the navigation tasks' continuous variant: (dx, dy)
        return as_vector(values, size, "action").astype(np.float32)


def main(args=None) -> int:
    return EnvSimNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
