"""agent: chooses actions from what it observes and publishes them as AgentAction.

observe "reward_step": acts on RewardStep.augmented_state [s_t, h'_{t+1}] (a reward model or the
oracle runs); observe "observation": acts on the raw EnvObservation state (no reward model).
policy "random": uniform over the task's action space (seeded); policy "sb3": a saved
stable-baselines3 policy (`policy_path`, a .zip from DQN or SAC; `algo` auto = DQN for the
discrete tasks, SAC for Lunar Lander), deterministic.

No action is sent for a final (terminated/truncated) input. A repeated input (same episode and
step, e.g. a re-published observation) gets the same action again. Learning through the graph comes
with the RL issue: it will subscribe to the same topics.
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node

from nmrm_msgs.msg import AgentAction, EnvObservation, RewardStep

from ..ros.messages import as_vector
from ..ros.node_main import (EXIT_WITH_UPSTREAM, NodeError, Param, declare_parameters,
                             exit_with_upstream, require_task, run_node)
from ..ros.topics import ACTION, OBSERVATION, REWARD_STEP, STEP_QOS

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "task": Param("key", "task (sets the action space)"),
    "observe": Param("reward_step", "reward_step | observation"),
    "policy": Param("random", "random | sb3"),
    "policy_path": Param("", "stable-baselines3 .zip (policy sb3)"),
    "algo": Param("auto", "auto | dqn | sac (policy sb3)"),
    "continuous": Param(False, "continuous-action variant of the navigation tasks"),
    "seed": Param(0, "seed of the random policy"),
}


class AgentNode(Node):
    def __init__(self) -> None:
        self.exit_code = None
        self.messages_received = 0
        super().__init__("agent")
        p = declare_parameters(self, PARAMETERS)
        self.info = require_task(p["task"])
        self.discrete = self.info.discrete and not p["continuous"]
        self.rng = np.random.default_rng(int(p["seed"]))
        self.policy = p["policy"]
        self.sb3 = None
        if self.policy == "sb3":
            self.sb3 = self._load_sb3(p["policy_path"], p["algo"])
        elif self.policy != "random":
            raise NodeError(f"unknown policy {self.policy!r}: use 'random' or 'sb3'")
        self.last_key = None
        self.last_action = None
        self.sent = 0
        self.dropped = 0
        self.pub = self.create_publisher(AgentAction, ACTION, STEP_QOS)
        if p["observe"] == "reward_step":
            self.sub = self.create_subscription(RewardStep, REWARD_STEP,
                                                lambda m: self.act(m, m.augmented_state), STEP_QOS)
        elif p["observe"] == "observation":
            self.sub = self.create_subscription(EnvObservation, OBSERVATION,
                                                lambda m: self.act(m, m.state), STEP_QOS)
        else:
            raise NodeError(f"unknown observe {p['observe']!r}: use 'reward_step' or 'observation'")
        if p["exit_with_upstream"]:
            exit_with_upstream(self, self.sub)

    def _load_sb3(self, path: str, algo: str):
        from pathlib import Path

        if not path or not Path(path).is_file():
            raise NodeError(f"policy sb3 needs an existing policy_path, got {path!r}")
        import stable_baselines3 as sb3

        if algo == "auto":
            algo = "dqn" if self.discrete else "sac"
        classes = {"dqn": sb3.DQN, "sac": sb3.SAC}
        if algo not in classes:
            raise NodeError(f"unknown algo {algo!r}: use auto, dqn or sac")
        try:
            return classes[algo].load(path, device="cpu")
        except Exception as exc:  # noqa: BLE001 - report any load failure as a config error
            raise NodeError(f"cannot load {algo} policy {path}: {exc}") from None

    def act(self, msg, observed) -> None:
        self.messages_received += 1
        if msg.terminated or msg.truncated:
            return
        key = (msg.episode, msg.step)
        if key == self.last_key:
            action = self.last_action
        else:
            try:
                obs = as_vector(observed, None, "observation")
                action = self.choose(obs)
            except ValueError as exc:
                self.dropped += 1
                self.get_logger().warning(f"no action for episode {msg.episode} step {msg.step}: {exc}")
                return
            self.last_key, self.last_action = key, action
        out = AgentAction(episode=msg.episode, step=msg.step, action=action)
        out.header.stamp = self.get_clock().now().to_msg()
        self.pub.publish(out)
        self.sent += 1

    def choose(self, obs: np.ndarray) -> list:
        if self.sb3 is not None:
            expected = self.sb3.observation_space.shape
            if obs.shape != expected:
                raise ValueError(f"observation of shape {obs.shape}, the policy takes {expected}")
            action, _ = self.sb3.predict(obs.astype(np.float32), deterministic=True)
            return [float(x) for x in np.asarray(action).reshape(-1)]
        if self.discrete:
            return [float(self.rng.integers(self.info.action_size))]
        return [float(x) for x in self.rng.uniform(-1.0, 1.0, 2)]


def main(args=None) -> int:
    return run_node(AgentNode, "agent", __doc__.strip().splitlines()[0], PARAMETERS, args)


if __name__ == "__main__":
    raise SystemExit(main())
