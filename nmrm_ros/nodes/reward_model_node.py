"""reward_model: serves a MIL reward model online, one observation at a time.

For every EnvObservation (episode e, step t, state s_t) it publishes a RewardStep with
h'_{t+1} (the hidden state after consuming s_t), the augmented state [s_t, h'_{t+1}] and the reward
r'_t. The hidden state is reset to h'_0 at step 0 of each episode. The episode's final observation
(terminated/truncated) gets a RewardStep too, flagged the same way: its augmented state is the
terminal state an RL agent bootstraps from; its reward belongs to no transition.

mode "model": the CSC / Instance / Embedding LSTM (or Instance NN) of `checkpoint`, stepped with
the NumPy online stepper. An ensemble checkpoint serves the members' mean reward, their spread in
`reward_std` / `return_std`, and the hidden state of its serving member (the best on validation). mode "oracle": the task's true hidden state and reward (the paper's
oracle baselines), through the same graph.

Ordering rule (`nmrm_ros.ros.episodes`): a re-published observation (same episode, step and state)
gets the same RewardStep again, without stepping; a missing or out-of-order step, a state of the
wrong size or with NaN breaks the episode: it is logged and counted, and nothing more is published
for it until the next step 0 (a wrong hidden state is never served).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rclpy.node import Node

from nmrm_msgs.msg import EnvObservation, RewardStep

from ..ros.episodes import EpisodeFollower, Kind
from ..ros.messages import to_float_list
from ..ros.node_main import (EXIT_WITH_UPSTREAM, NodeError, Param, declare_parameters,
                             exit_with_upstream, require_task, run_node)
from ..ros.topics import OBSERVATION, REWARD_STEP, STEP_QOS

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "mode": Param("model", "model | oracle"),
    "checkpoint": Param("", "MIL checkpoint (path to .pt/.json or their stem), mode model"),
    "task": Param("", "task; mode oracle: required; mode model: checked against the checkpoint"),
    "source": Param("", "id published in RewardStep.source (default: checkpoint name or 'oracle')"),
}


class RewardModelNode(Node):
    def __init__(self) -> None:
        self.exit_code = None
        self.messages_received = 0
        super().__init__("reward_model")
        p = declare_parameters(self, PARAMETERS)
        mode = p["mode"]
        if mode == "oracle":
            from ..oracles import make_oracle

            if not p["task"]:
                raise NodeError("mode oracle needs the parameter task")
            self.info = require_task(p["task"])
            self.stepper = make_oracle(p["task"]).tracker()
            self.source = p["source"] or "oracle"
        elif mode == "model":
            from ..mil import CheckpointError, OnlineRewardModel, load_checkpoint

            if not p["checkpoint"]:
                raise NodeError("mode model needs the parameter checkpoint")
            try:
                model, meta = load_checkpoint(p["checkpoint"], task=p["task"] or None)
                self.info = require_task(meta["task"])
            except (CheckpointError, ValueError) as exc:
                raise NodeError(str(exc)) from None
            if model.config.input_size != self.info.state_size:
                raise NodeError(f"checkpoint takes states of size {model.config.input_size}, task "
                                f"{meta['task']} has {self.info.state_size}")
            self.stepper = OnlineRewardModel(model)
            self.source = p["source"] or Path(p["checkpoint"]).with_suffix("").name
        else:
            raise NodeError(f"unknown mode {mode!r}: use 'model' or 'oracle'")
        self.task = self.info.name
        self.follower = EpisodeFollower()
        self.last: RewardStep | None = None
        self.compute_s: list = []
        self.pub = self.create_publisher(RewardStep, REWARD_STEP, STEP_QOS)
        self.sub = self.create_subscription(EnvObservation, OBSERVATION, self.on_observation, STEP_QOS)
        if p["exit_with_upstream"]:
            exit_with_upstream(self, self.sub)
        self.get_logger().info(f"{mode} mode, task {self.task}, source {self.source!r}")

    def on_observation(self, msg: EnvObservation) -> None:
        self.messages_received += 1
        kind, state, why = self.follower.follow(msg, self.task, self.info.state_size)
        if kind is Kind.DUPLICATE and self.last is not None:
            self.pub.publish(self.last)
            return
        if kind is Kind.BROKEN:
            if self.follower.just_broke:
                self.get_logger().warning(f"episode {msg.episode} broken at step {msg.step} "
                                          f"({self.follower.broken_episodes} so far): {why}; "
                                          f"waiting for the next step 0")
            return
        t0 = time.perf_counter()
        if kind is Kind.START:
            self.stepper.reset()
        reward, hidden = self.stepper.step(state)
        self.compute_s.append(time.perf_counter() - t0)
        if msg.terminated or msg.truncated:
            self.follower.finish()
        out = RewardStep(episode=msg.episode, step=msg.step, state=list(msg.state),
                         hidden=to_float_list(hidden),
                         augmented_state=to_float_list(np.concatenate([state, hidden])),
                         reward=float(reward), reward_std=float(getattr(self.stepper, "reward_std", 0.0)),
                         return_std=float(getattr(self.stepper, "return_std", 0.0)), source=self.source,
                         terminated=msg.terminated, truncated=msg.truncated)
        out.header = msg.header
        self.last = out
        self.pub.publish(out)

    def close(self) -> None:
        if self.compute_s:
            us = np.asarray(self.compute_s) * 1e6
            self.get_logger().info(f"{len(us)} steps, compute per step: median {np.median(us):.1f} µs, "
                                   f"p99 {np.percentile(us, 99):.1f} µs; {self.follower.broken_episodes} broken episode(s)")


def main(args=None) -> int:
    return run_node(RewardModelNode, "reward_model", __doc__.strip().splitlines()[0], PARAMETERS, args)


if __name__ == "__main__":
    raise SystemExit(main())
