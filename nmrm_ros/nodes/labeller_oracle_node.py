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

Feedback: `feedback` returns (the default: a TrajectoryReturn per episode), preferences or both.
With preferences, each finished episode is compared with `pairs_per_episode` episodes drawn from
the last `pair_pool` finished ones, by a simulated teacher with B-Pref's knobs (`teacher_beta`,
`teacher_mistake`, `teacher_equal`, `teacher_gamma`, `teacher_skip`;
`nmrm_ros.datasets.preference_teacher`), and the answers are published as TrajectoryPreference on
`nmrm/trajectory_preference` (labeller oracle/<task> for a perfect teacher, else teacher/<task>).

Simulated label noise, seeded by `noise_seed`: `label_noise` "gaussian" adds Gaussian noise of std
`label_noise_std` (0: none) to the published return; "swap" is the paper's label swapping (Sec.
5.2) online: a fraction `label_swap` of the episodes get the true return of one of the last
`swap_pool` episodes, which takes theirs in exchange (`nmrm_ros.datasets.OnlineLabelSwapper`).
"""

from __future__ import annotations

import numpy as np

import math
from collections import deque

from nmrm_msgs.msg import EnvObservation, OracleStep, TrajectoryPreference, TrajectoryReturn

from ..ros.episodes import EpisodeFollower, Kind
from ..ros.messages import oracle_state, to_float_list
from ..datasets.label_noise import OnlineLabelSwapper
from ..datasets.preference_teacher import SimulatedTeacher
from ..feedback import unknown_feedback
from ..ros.node_base import NmrmNode
from ..ros.node_main import (EXIT_WITH_UPSTREAM, ORACLE, NodeError, Param,
                             require_oracle, require_task)
from ..ros.topics import OBSERVATION, ORACLE_STEP, STEP_QOS, TRAJECTORY_PREFERENCE, TRAJECTORY_RETURN

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "task": Param("key", "task whose oracle labels the episodes"),
    "oracle": ORACLE,
    "publish_oracle_steps": Param(True, "also publish per-step ground truth (OracleStep)"),
    "label_noise": Param("gaussian", "gaussian (label_noise_std) | swap (label_swap, swap_pool)"),
    "label_noise_std": Param(0.0, "label_noise gaussian: std of the noise added to each return", 0.0),
    "label_swap": Param(0.0, "label_noise swap: fraction of episodes whose label is swapped", 0.0),
    "swap_pool": Param(50, "label_noise swap: recent episodes whose true returns are swapped within", 1),
    "noise_seed": Param(0, "seed of the label noise and of the teacher's pairs and answers"),
    "feedback": Param("returns", "returns | preferences | both: what is published per finished episode"),
    "pairs_per_episode": Param(1, "feedback preferences|both: comparisons of each finished episode", 1),
    "pair_pool": Param(20, "feedback preferences|both: recent episodes a new one is compared with", 1),
    "teacher_beta": Param(math.inf, "teacher rationality: P(a better) = sigmoid(beta (R_a - R_b)); "
                                    "inf (YAML .inf): always the better one"),
    "teacher_mistake": Param(0.0, "teacher: probability of flipping an answer", 0.0),
    "teacher_equal": Param(0.0, "teacher: returns this close are 'equal'", 0.0),
    "teacher_gamma": Param(1.0, "teacher myopia in (0, 1]: step t weighs gamma^(len - 1 - t)", 0.0),
    "teacher_skip": Param(-math.inf, "teacher: no answer when both returns are below this"),
}


class LabellerOracleNode(NmrmNode):
    executable = "labeller_oracle"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        self.messages_received = 0
        super().__init__()
        p = self.params
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
        self.feedback = p["feedback"]
        if unknown_feedback(self.feedback):
            raise NodeError(unknown_feedback(self.feedback))
        try:
            self.teacher = SimulatedTeacher(p["teacher_beta"], p["teacher_mistake"], p["teacher_equal"],
                                            p["teacher_gamma"], p["teacher_skip"]).check()
        except ValueError as exc:
            raise NodeError(str(exc).replace("teacher setting ", "teacher_")) from None
        perfect = self.teacher == SimulatedTeacher()
        self.pref_labeller = f"{'oracle' if perfect else 'teacher'}/{self.task}"
        self.pairs_per_episode = int(p["pairs_per_episode"])
        self.recent: deque = deque(maxlen=int(p["pair_pool"]))  # (episode, length, judged return)
        self.rewards: list = []  # this episode's oracle rewards so far
        self.compared = 0
        self.return_pub = self.create_publisher(TrajectoryReturn, TRAJECTORY_RETURN, STEP_QOS)
        self.pref_pub = self.create_publisher(TrajectoryPreference, TRAJECTORY_PREFERENCE, STEP_QOS)
        self.step_pub = self.create_publisher(OracleStep, ORACLE_STEP, STEP_QOS)
        self.exit_with_upstream(self.subscribe_steps(EnvObservation, OBSERVATION, self.on_observation, self.info))
        self.diagnose(lambda: {"steps": self.messages_received, "labelled_episodes": self.labelled,
            "comparisons": self.compared, "broken_episodes": self.follower.broken_episodes},
            rate_of="steps",
            warn=lambda: f"{self.follower.broken_episodes} broken episode(s)" if self.follower.broken_episodes else None)

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
            self.rewards = []
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
            if self.feedback != "preferences":
                out = TrajectoryReturn(task=self.task, episode=msg.episode, length=msg.step,
                                       return_value=float(value), labeller=self.labeller)
                out.header.stamp = self.get_clock().now().to_msg()
                self.return_pub.publish(out)
                self.labelled += 1
            if self.feedback != "returns":
                self.compare(int(msg.episode), int(msg.step))
            return
        try:
            reward, hidden = self.tracker.step(oracle_state(msg, state, self.info.privileged_size))
        except ValueError as exc:  # a user's oracle that misbehaved, or no privileged state (one line)
            self.follower.break_episode(msg.episode)
            self.log_broken(msg, str(exc))
            return
        self.rewards.append(float(reward))
        if self.publish_steps:
            step = OracleStep(episode=msg.episode, step=msg.step, hidden=to_float_list(hidden),
                              reward=float(reward))
            step.header = msg.header
            self.step_pub.publish(step)

    def compare(self, episode: int, length: int) -> None:
        """The teacher's answers on the finished episode against recent ones, published."""
        judged = self.teacher.judge(self.rewards)
        if self.recent:
            picks = self.rng.choice(len(self.recent), size=min(self.pairs_per_episode, len(self.recent)),
                                    replace=False)
            for i in picks:
                other, other_length, other_judged = self.recent[int(i)]
                first = self.rng.random() < 0.5  # which one is shown as a is random
                a, b = ((episode, length, judged), (other, other_length, other_judged))[::1 if first else -1]
                p, answered = self.teacher.decide(a[2], b[2], self.rng)
                if not answered[0]:
                    continue
                out = TrajectoryPreference(task=self.task, episode_a=a[0], length_a=a[1], episode_b=b[0],
                                           length_b=b[1], preference=int(round(2 * p[0] - 1)),
                                           labeller=self.pref_labeller)
                out.header.stamp = self.get_clock().now().to_msg()
                self.pref_pub.publish(out)
                self.compared += 1
        self.recent.append((episode, length, judged))

    def close(self) -> None:
        swapped = f", {self.swapper.swapped} label(s) swapped" if self.swapper is not None else ""
        compared = f", {self.compared} comparison(s)" if self.feedback != "returns" else ""
        self.get_logger().info(f"labelled {self.labelled} episode(s), {self.follower.broken_episodes} broken"
                               f"{swapped}{compared}")


def main(args=None) -> int:
    return LabellerOracleNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
