"""labeller_oracle: watches trajectories and publishes their returns, computed by the task's oracle.

THE LABELLER CONTRACT (what a human-labelling node implements too; see docs/guide/graph.md):
- subscribes to `nmrm/observation` (EnvObservation; may also use `nmrm/action`);
- an episode is identified by (task, episode) of its observations; it is complete when the
  observation with `terminated` or `truncated` set arrives, whose `step` is the episode length L;
- publishes exactly one TrajectoryReturn(task, episode, length=L, return_value, labeller) per
  complete episode it labels, after that final observation (a person may take longer; nothing
  waits for the label). Episodes that it could not follow in full are not labelled.
This oracle labeller also publishes, if `publish_oracle_steps`, one OracleStep per step t < L with
the true h_{t+1} and r_t (for evaluation only).

The oracle is the task's own, or `oracle` (a user's function of the trajectory so far; it gets
actions None, since this node follows observations only). An episode on which it fails (raises,
a wrong shape, NaN) is broken: logged in one line, not labelled.

Observations are followed with the rule of `nmrm_ros.ros.episodes` (duplicates ignored, a gap or
disorder breaks the episode); a state of the wrong size or with NaN breaks the episode too. Broken
episodes are counted and logged, never labelled.

Simulated label noise, seeded by `noise_seed`: `label_noise` "gaussian" adds Gaussian noise of std
`label_noise_std` (0: none) to the published return; "swap" is the paper's label swapping (Sec.
5.2) online: a fraction `label_swap` of the episodes get the true return of one of the last
`swap_pool` episodes, which takes theirs in exchange (`nmrm_ros.datasets.OnlineLabelSwapper`).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node

from nmrm_msgs.msg import EnvObservation, OracleStep, TrajectoryReturn

from ..ros.episodes import EpisodeFollower, Kind
from ..ros.messages import to_float_list
from ..datasets.label_noise import OnlineLabelSwapper
from ..ros.node_main import (EXIT_WITH_UPSTREAM, ORACLE, NodeError, Param, declare_parameters,
                             exit_with_upstream, require_oracle, require_task, run_node)
from ..ros.topics import OBSERVATION, ORACLE_STEP, STEP_QOS, TRAJECTORY_RETURN

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "task": Param("key", "task whose oracle labels the episodes"),
    "oracle": ORACLE,
    "publish_oracle_steps": Param(True, "also publish per-step ground truth (OracleStep)"),
    "label_noise": Param("gaussian", "gaussian (label_noise_std) | swap (label_swap, swap_pool)"),
    "label_noise_std": Param(0.0, "label_noise gaussian: std of the noise added to each return", 0.0),
    "label_swap": Param(0.0, "label_noise swap: fraction of episodes whose label is swapped", 0.0),
    "swap_pool": Param(50, "label_noise swap: recent episodes whose true returns are swapped within", 1),
    "noise_seed": Param(0, "seed of the label noise"),
}


class LabellerOracleNode(Node):
    def __init__(self) -> None:
        self.exit_code = None
        self.messages_received = 0
        super().__init__("labeller_oracle")
        p = declare_parameters(self, PARAMETERS)
        self.info = require_task(p["task"])
        self.task = p["task"]
        self.oracle = require_oracle(self.task, p["oracle"])
        self.tracker = self.oracle.tracker()
        self.follower = EpisodeFollower()
        self.publish_steps = bool(p["publish_oracle_steps"])
        self.noise_std = float(p["label_noise_std"])
        self.rng = np.random.default_rng(int(p["noise_seed"]))
        self.swapper = None
        if p["label_noise"] == "swap":
            if not p["label_swap"] <= 1.0:
                raise NodeError(f"label_swap must be a fraction in [0, 1], got {p['label_swap']}")
            self.swapper = OnlineLabelSwapper(float(p["label_swap"]), int(p["swap_pool"]), self.rng)
        elif p["label_noise"] != "gaussian":
            raise NodeError(f"unknown label_noise {p['label_noise']!r}: use 'gaussian' or 'swap'")
        self.labeller = f"oracle/{self.task}"
        self.labelled = 0
        self.return_pub = self.create_publisher(TrajectoryReturn, TRAJECTORY_RETURN, STEP_QOS)
        self.step_pub = self.create_publisher(OracleStep, ORACLE_STEP, STEP_QOS)
        self.sub = self.create_subscription(EnvObservation, OBSERVATION, self.on_observation, STEP_QOS)
        if p["exit_with_upstream"]:
            exit_with_upstream(self, self.sub)

    def log_broken(self, msg: EnvObservation, why: str) -> None:
        self.get_logger().warning(f"episode {msg.episode} not labelled "
                                  f"({self.follower.broken_episodes} so far): {why}")

    def on_observation(self, msg: EnvObservation) -> None:
        self.messages_received += 1
        kind, state, why = self.follower.follow(msg, self.task, self.info.state_size)
        if kind is Kind.DUPLICATE:
            return
        if kind is Kind.BROKEN:
            if self.follower.just_broke:
                self.log_broken(msg, why)
            return
        if kind is Kind.START:
            self.tracker.reset()
        if msg.terminated or msg.truncated:
            if msg.step == 0:
                self.follower.break_episode(msg.episode)
                self.log_broken(msg, "final observation at step 0")
                return
            self.follower.finish()
            if self.swapper is not None:
                value = self.swapper.label(self.tracker.total)
            else:
                value = self.tracker.total + (self.rng.normal(0.0, self.noise_std) if self.noise_std > 0 else 0.0)
            out = TrajectoryReturn(task=self.task, episode=msg.episode, length=msg.step,
                                   return_value=float(value), labeller=self.labeller)
            out.header.stamp = self.get_clock().now().to_msg()
            self.return_pub.publish(out)
            self.labelled += 1
            return
        try:
            reward, hidden = self.tracker.step(state)
        except ValueError as exc:  # a user's oracle that misbehaved on this episode (OracleError)
            self.follower.break_episode(msg.episode)
            self.log_broken(msg, str(exc))
            return
        if self.publish_steps:
            step = OracleStep(episode=msg.episode, step=msg.step, hidden=to_float_list(hidden),
                              reward=float(reward))
            step.header = msg.header
            self.step_pub.publish(step)

    def close(self) -> None:
        swapped = f", {self.swapper.swapped} label(s) swapped" if self.swapper is not None else ""
        self.get_logger().info(f"labelled {self.labelled} episode(s), {self.follower.broken_episodes} broken"
                               f"{swapped}")


def main(args=None) -> int:
    return run_node(LabellerOracleNode, "labeller_oracle", __doc__.strip().splitlines()[0], PARAMETERS, args)


if __name__ == "__main__":
    raise SystemExit(main())
