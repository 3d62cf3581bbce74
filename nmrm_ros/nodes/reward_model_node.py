"""reward_model: serves a MIL reward model online, one observation at a time.

For every EnvObservation (episode e, step t, state s_t) it publishes a RewardStep with the
served hidden state after consuming s_t, the augmented state [s_t, served] and the reward r'_t.
What is served (`served_state`): "h_tanh_c", the LSTM's full recurrent state
[h'_{t+1}, tanh c'_{t+1}] (2k values; the default, because the output gate can hide the model's
memory from h' alone: `nmrm_ros.mil.served_state`), "h_c" the raw [h', c'], or "h", h'_{t+1}
only (the paper's choice). The recurrent state is
reset to (h'_0, c'_0) at step 0 of each episode. The episode's final observation
(terminated/truncated) gets a RewardStep too, flagged the same way: its augmented state is the
terminal state an RL agent bootstraps from; its reward belongs to no transition.
On an image task the observation's pixels come on `nmrm/observation_image` beside it (joined by
`NmrmNode.subscribe_steps`), and RewardStep's `state` and `augmented_state` leave them out
([vector part], [vector part, served]): a consumer joins them with the same image.

mode "model": the CSC / Instance / Embedding LSTM (or Instance NN) of `checkpoint`, stepped with
the NumPy online stepper. An ensemble checkpoint serves the members' mean reward, their spread in
`reward_std` / `return_std`, and the hidden state of its serving member (the best on validation). mode "oracle": the task's true hidden state and reward (the paper's
oracle baselines), through the same graph; `oracle` names a user's oracle function instead
(`nmrm_ros.oracles.function_oracle`; an episode on which it fails is broken, logged in one line).

Live reload (mode model): setting `checkpoint` while the node runs (`ros2 param set /reward_model
checkpoint PATH`, or the trainer node after each retraining) loads and checks the new model at
once (a bad one is refused with its reason, and serving goes on unchanged) and swaps it in at the
next episode start, never mid-episode. `RewardStep.source` names the model serving each step: the
checkpoint's name (e.g. key_v003), or `source` if given; the new model must take the same task
and hidden size, so that the agent's augmented state keeps its size.

Ordering rule (`nmrm_ros.ros.episodes`): a re-published observation (same episode, step and state)
gets the same RewardStep again, without stepping; a missing or out-of-order step, a state of the
wrong size or with NaN breaks the episode: it is logged and counted, and nothing more is published
for it until the next step 0 (a wrong hidden state is never served).
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path

import numpy as np

from nmrm_msgs.msg import EnvObservation, RewardStep

from ..ros.episodes import EpisodeFollower, Kind
from ..ros.messages import oracle_state, to_float_list
from ..ros.node_base import NmrmNode
from ..ros.node_main import (EXIT_WITH_UPSTREAM, ORACLE, NodeError, Param,
                             live_parameter, require_oracle, require_task)
from ..ros.topics import OBSERVATION, REWARD_STEP, STEP_QOS

#: steps whose compute time is kept for the summary at exit (a node may serve for days)
COMPUTE_WINDOW = 100_000

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "mode": Param("model", "model | oracle"),
    "checkpoint": Param("", "MIL checkpoint (path to .pt/.json or their stem), mode model"),
    "task": Param("", "task; mode oracle: required; mode model: checked against the checkpoint"),
    "oracle": ORACLE,
    "source": Param("", "id published in RewardStep.source (default: checkpoint name or 'oracle'); "
                        "kept across live reloads"),
    "served_state": Param("", "mode model: the hidden state served, h_tanh_c ([h', tanh c'] of the LSTM, "
                              "2k values), h_c ([h', c']) or h (h' only, k values, as the paper); '' = the "
                              "checkpoint's (its training config's served_state), kept across live reloads"),
}


class RewardModelNode(NmrmNode):
    executable = "reward_model"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        self.messages_received = 0
        super().__init__()
        p = self.params
        mode = p["mode"]
        if mode == "oracle":
            if not p["task"]:
                raise NodeError("mode oracle needs the parameter task")
            self.info = require_task(p["task"])
            self.stepper = require_oracle(p["task"], p["oracle"]).tracker()
            self.source = p["source"] or "oracle"
        elif mode == "model":
            if not p["checkpoint"]:
                raise NodeError("mode model needs the parameter checkpoint")
            from ..mil.served_state import SERVED_STATES

            if p["served_state"] and p["served_state"] not in SERVED_STATES:
                raise NodeError(f"served_state must be one of {', '.join(SERVED_STATES)} or '' (the "
                                f"checkpoint's), got {p['served_state']!r}")
            self.served = p["served_state"] or None  # None: the first checkpoint's, then kept
            stepper, self.info, error = self._load(p["checkpoint"], p["task"] or None)
            if error:
                raise NodeError(error)
            self.stepper = stepper
            self.source = p["source"] or Path(p["checkpoint"]).with_suffix("").name
        else:
            raise NodeError(f"unknown mode {mode!r}: use 'model' or 'oracle'")
        self.task = self.info.name
        self.mode, self.fixed_source = mode, p["source"]
        self.pending: tuple | None = None  # (stepper, source) loaded live, swapped in at the next step 0
        live_parameter(self, PARAMETERS, "checkpoint", self._reload)
        self.follower = EpisodeFollower()
        self.last: RewardStep | None = None
        self.compute_s: deque = deque(maxlen=COMPUTE_WINDOW)  # the last steps' compute times (s)
        self.steps_computed = 0
        self.pub = self.create_publisher(RewardStep, REWARD_STEP, STEP_QOS)
        self.subs = self.subscribe_steps(EnvObservation, OBSERVATION, self.on_observation, self.info)
        self.exit_with_upstream(self.subs)
        served = f", serving [s_t, {self.served}]" if mode == "model" else ""
        self.get_logger().info(f"{mode} mode, task {self.task}, source {self.source!r}{served}")
        self.diagnose(lambda: {"steps": self.messages_received, "broken_episodes": self.follower.broken_episodes,
            "mode": self.mode, "model": self.source}, rate_of="steps", hardware_id=self.task,
            warn=lambda: f"{self.follower.broken_episodes} broken episode(s)" if self.follower.broken_episodes else None)

    def _load(self, path: str, task: str | None):
        """(online stepper, task info, '') of a checkpoint, or (None, None, why not)."""
        from ..mil import CheckpointError, OnlineRewardModel

        try:
            stepper = OnlineRewardModel.from_checkpoint(path, task=task, served=self.served)
            info = require_task(stepper.task)
            if stepper.input_size != info.state_size:  # a checkpoint's task of another size
                raise ValueError(f"checkpoint takes states of size {stepper.input_size}, task "
                                 f"{stepper.task} has {info.state_size}")
        except (CheckpointError, ValueError, NodeError) as exc:
            return None, None, str(exc)
        self.served = stepper.served
        return stepper, info, ""

    def _reload(self, value) -> str:
        """A new `checkpoint` set while running: load and check it now, serve it from the next
        step 0; '' or why it is refused."""
        if self.mode != "model":
            return "mode oracle serves no checkpoint"
        stepper, _, error = self._load(str(value), self.task)
        if error:
            return error
        if len(stepper.hidden) != len(self.stepper.hidden):
            return (f"its hidden state has size {len(stepper.hidden)}, the model served has "
                    f"{len(self.stepper.hidden)} (the augmented state would change size)")
        self.pending = (stepper, self.fixed_source or Path(str(value)).with_suffix("").name)
        self.get_logger().info(f"loaded {value}; serving it from the next episode")
        return ""

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
            if self.pending is not None:
                (self.stepper, self.source), self.pending = self.pending, None
                self.get_logger().info(f"episode {msg.episode}: now serving {self.source}")
            self.stepper.reset()
        try:
            reward, hidden = self.stepper.step(oracle_state(msg, state, self.info.privileged_size)
                                               if self.mode == "oracle" else state)
        except ValueError as exc:  # a user's oracle that misbehaved, or no privileged state (one line)
            if self.follower.break_episode(msg.episode):
                self.get_logger().error(f"episode {msg.episode} broken at step {msg.step}: {exc}; "
                                        f"waiting for the next step 0")
            return
        self.compute_s.append(time.perf_counter() - t0)
        self.steps_computed += 1
        if msg.terminated or msg.truncated:
            self.follower.finish()
        vector = state[self.info.image_values:]  # an image task's pixels travel as its observation image
        out = RewardStep(episode=msg.episode, step=msg.step, state=to_float_list(vector),
                         hidden=to_float_list(hidden),
                         augmented_state=to_float_list(np.concatenate([vector, hidden])),
                         reward=float(reward), reward_std=float(getattr(self.stepper, "reward_std", 0.0)),
                         return_std=float(getattr(self.stepper, "return_std", 0.0)), source=self.source,
                         terminated=msg.terminated, truncated=msg.truncated)
        out.header = msg.header
        self.last = out
        self.pub.publish(out)

    def close(self) -> None:
        if self.compute_s:
            us = np.asarray(self.compute_s) * 1e6
            window = f" (the last {len(us)})" if len(us) < self.steps_computed else ""
            self.get_logger().info(f"{self.steps_computed} steps, compute per step{window}: median {np.median(us):.1f} µs, "
                                   f"p99 {np.percentile(us, 99):.1f} µs; {self.follower.broken_episodes} broken episode(s)")


def main(args=None) -> int:
    return RewardModelNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
