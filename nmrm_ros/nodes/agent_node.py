"""agent: chooses actions from what it observes and publishes them as AgentAction.

observe "reward_step": acts on RewardStep.augmented_state [s_t, h'_{t+1}] (a reward model or the
oracle runs); observe "observation": acts on the raw EnvObservation state (no reward model).
policy "random": uniform over the task's action space (seeded); policy "sb3": a saved
stable-baselines3 policy (`policy_path`, a .zip from DQN or SAC; `algo` auto = DQN for the
discrete tasks, SAC for Lunar Lander), deterministic.

policy "learn": trains the paper's agent (double DQN, or SAC for Lunar Lander; config/rl.yaml)
online from the RewardStep messages. SB3's own `learn()` runs in a learner thread on a
`TopicEnv` (nmrm_ros/ros/topic_env.py), a gymnasium Env that is a bridge to the topics: the
transition (s_t, a_t, r'_t, s_{t+1}) is the one the gymnasium wrappers give without ROS. The
learner starts at the first step 0 it sees, plans its epsilon schedule over `episodes` episodes,
and stops after them (then the node exits 0) or when the graph ends. Into `out` it writes
policy.zip, curve.csv (learnt return per episode, and the oracle return when a labeller publishes
TrajectoryReturn) and agent.json every `save_every` episodes and at exit (Ctrl-C/SIGTERM too);
`save_replay_buffer` adds replay_buffer.pkl. Progress is logged every `log_every` episodes.

A reward model retrained while the agent learns (the trainer node; the reward-model <-> agent
loop, launch_scripts/loop.launch.yaml) changes what the agent's rewards and hidden states mean.
`checkpoint` (settable while running; the trainer sets it with the reward model's) names the
model being served: once RewardStep.source names it (the reward model has swapped it in, at an
episode start), the agent relabels its whole replay buffer with it (rewards r'_t and served
states h'_{t+1} recomputed from the stored states, `nmrm_ros.rl.replay_relabel`) before it acts
again, and keeps its networks. At the end, when `checkpoint`'s model served the last 50 episodes
and a labeller judged them, one line says what the model paid them against the labeller's returns
(`nmrm_ros.rl.model_check`, `nmrm check`'s tolerance; agent.json's `model_check`): a FAIL says the
agent went where the model is wrong, and the loop is what repairs that.

No action is sent for a final (terminated/truncated) input. A repeated input (same episode and
step, e.g. a re-published observation) gets the same action again. The action topic is advertised
only once the input topic has a publisher matched, so a real-time bridge that waits for an agent
starts when the agent can see its episodes.

`robots` (a fleet): one agent for several namespaced graphs, e.g. [/robot1, /robot2]: it
subscribes to each robot's `<robot>/nmrm/...` topics and answers each on its own action topic.
With policy learn, one policy learns from all of them at once: one TopicEnv per robot, stepped
concurrently as one SB3 vectorised env (`nmrm_ros.ros.topic_vec_env.ThreadedVecEnv`); `episodes`
then counts the fleet's episodes, each robot playing ceil(episodes / N) of them, and SB3 makes
`gradient_steps` per fleet step (N transitions). Episodes of fixed length (the navigation tasks)
keep the robots in step; with Lunar Lander a robot that has played its share first sends
zero-observation "after the last episode" steps (not counted as episodes) until the others finish.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from rclpy.publisher import Publisher

from nmrm_msgs.msg import AgentAction, EnvObservation, RewardStep, TrajectoryReturn

from ..ros.messages import as_vector
from ..ros.node_base import NmrmNode
from ..ros.node_main import (EXIT_WITH_UPSTREAM, NodeError, Param,
                             live_parameter, require_task)
from ..ros.topics import ACTION, OBSERVATION, REWARD_STEP, STEP_QOS, TRAJECTORY_RETURN

PARAMETERS = {
    "exit_with_upstream": EXIT_WITH_UPSTREAM,
    "task": Param("key", "task (sets the action space)"),
    "observe": Param("reward_step", "reward_step | observation"),
    "policy": Param("random", "random | sb3 | learn"),
    "policy_path": Param("", "stable-baselines3 .zip (policy sb3)"),
    "algo": Param("auto", "auto | dqn | sac (policy sb3)"),
    "continuous": Param(False, "continuous-action variant of the navigation tasks"),
    "seed": Param(0, "seed of the random policy / of the learner (SB3 seed)"),
    "episodes": Param(0, "policy learn: episodes to learn for (epsilon schedule, stop); 0 = config/rl.yaml", 0),
    "out": Param("runs/agent", "policy learn: output directory (policy.zip, curve.csv, agent.json)"),
    "save_every": Param(50, "policy learn: save the policy every this many episodes (0 = only at exit)", 0),
    "log_every": Param(10, "policy learn: log progress every this many episodes", 1),
    "observe_hidden": Param(True, "policy learn: observe augmented_state (false: the raw state only)"),
    "learning_starts": Param(-1, "policy learn: random steps before learning; -1 = config/rl.yaml", -1),
    "save_replay_buffer": Param(False, "policy learn: also save replay_buffer.pkl"),
    "rl_config": Param("", "policy learn: RL config YAML (default config/rl.yaml)"),
    "robots": Param([""], "namespaces of the graphs to act in (a fleet, e.g. [/robot1, /robot2]); "
                          "'' = this node's own"),
    "overlap_training": Param(True, "policy learn, one robot: run each gradient step while the graph computes the "
                                    "next state (one step behind SB3's order, nmrm_ros/rl/overlapped_training.py); "
                                    "false: SB3's order, the same transitions and weights as `nmrm rl train`"),
    "checkpoint": Param("", "policy learn: the reward model's checkpoint, settable while running (the "
                            "trainer sets it): the replay buffer is relabelled with it once RewardStep.source "
                            "names it ('' = never relabel), and the run ends checking it against the labels"),
}


def robot_topic(robot: str, topic: str) -> str:
    """`topic` (relative, e.g. nmrm/action) of robot namespace `robot` ('' = the node's own)."""
    return f"/{robot.strip('/')}/{topic}" if robot.strip("/") else topic


class AgentNode(NmrmNode):
    executable = "agent"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        self.messages_received = 0
        super().__init__()
        p = self.params
        self.info = require_task(p["task"])
        self.discrete = self.info.discrete and not p["continuous"]
        self.rng = np.random.default_rng(int(p["seed"]))
        self.policy = p["policy"]
        self.sb3 = None
        self.learner: Learner | None = None
        if self.policy == "sb3":
            self.sb3 = self._load_sb3(p["policy_path"], p["algo"])
        elif self.policy == "learn":
            if p["observe"] != "reward_step":
                raise NodeError("policy learn needs observe reward_step (rewards come with RewardStep)")
            self.learner = Learner(self, p)
            live_parameter(self, PARAMETERS, "checkpoint", self.learner.new_checkpoint)
        elif self.policy != "random":
            raise NodeError(f"unknown policy {self.policy!r}: use 'random', 'sb3' or 'learn'")
        self.robots = list(p["robots"]) or [""]
        if len(set(self.robots)) != len(self.robots):
            raise NodeError(f"robots {self.robots} name a namespace twice")
        n = len(self.robots)
        self.last_key: list = [None] * n
        self.last_action: list = [None] * n
        self.sent = 0
        self.dropped = 0
        # robot i's nmrm/action is advertised once its input stream is matched (_open_outputs)
        self.pubs: list = [None] * n
        self.pubs_lock = threading.Lock()  # the learner thread publishes too
        self.subs: list = []
        self.label_subs: list = []  # one per robot (learner only): its labeller's TrajectoryReturns
        if p["observe"] not in ("reward_step", "observation"):
            raise NodeError(f"unknown observe {p['observe']!r}: use 'reward_step' or 'observation'")
        for i, robot in enumerate(self.robots):
            # on an image task: the pixels joined from robot i's nmrm/observation_image
            if self.learner is not None:
                subs = self.subscribe_steps(RewardStep, robot_topic(robot, REWARD_STEP),
                                            lambda m, i=i: self.learner.on_reward_step(m, i), self.info,
                                            fields=("state", "augmented_state"))
                self.label_subs.append(self.create_subscription(
                    TrajectoryReturn, robot_topic(robot, TRAJECTORY_RETURN),
                    lambda m, i=i: self.learner.on_label(m, i), STEP_QOS))
            elif p["observe"] == "reward_step":
                subs = self.subscribe_steps(RewardStep, robot_topic(robot, REWARD_STEP),
                                            lambda m, i=i: self.act(m, m.augmented_state, i), self.info,
                                            fields=("state", "augmented_state"))
            else:
                subs = self.subscribe_steps(EnvObservation, robot_topic(robot, OBSERVATION),
                                            lambda m, i=i: self.act(m, m.state, i), self.info)
            self.subs.append(subs[0])  # robot i's step topic (its image topic beside it: subs[1:])
        self.sub = self.subs[0]
        self.output_timer = self.create_timer(0.05, self._open_outputs)
        self.exit_with_upstream(self.subs)
        self.diagnose(lambda: {"actions": self.sent, "dropped": self.dropped, "policy": self.policy},
            rate_of="actions", warn=lambda: f"{self.dropped} observation(s) without an action" if self.dropped else None)

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

    def act(self, msg, observed, robot: int = 0) -> None:
        self.messages_received += 1
        if msg.terminated or msg.truncated:
            return
        key = (msg.episode, msg.step)
        if key == self.last_key[robot]:
            action = self.last_action[robot]
        else:
            try:
                obs = as_vector(observed, None, "observation")
                action = self.choose(obs)
            except ValueError as exc:
                self.dropped += 1
                self.get_logger().warning(f"no action for episode {msg.episode} step {msg.step}: {exc}")
                return
            self.last_key[robot], self.last_action[robot] = key, action
        self.publish_action(msg.episode, msg.step, action, robot)

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

    def _open_outputs(self) -> None:
        """Advertise robot i's nmrm/action once robot i's input subscription has a publisher
        matched. A real-time bridge that waits for an agent (observation_bridge wait_for_agent)
        waits for this publisher: advertised at start, it let the bridge run a learning agent's
        4 episodes while DDS had not yet matched the agent's RewardStep subscription (a full test
        run, two workers: the agent saw no step 0, learnt nothing; the recorder got all 84 steps)."""
        for i, sub in enumerate(self.subs):
            if sub.get_publisher_count() > 0:
                self._output(i)
        if all(pub is not None for pub in self.pubs):
            self.output_timer.cancel()

    def _output(self, robot: int) -> Publisher:
        """Robot `robot`'s action publisher, advertised now if it was not yet."""
        with self.pubs_lock:
            if self.pubs[robot] is None:
                self.pubs[robot] = self.create_publisher(AgentAction, robot_topic(self.robots[robot], ACTION),
                                                         STEP_QOS)
            return self.pubs[robot]

    def publish_action(self, episode: int, step: int, action: list, robot: int = 0) -> None:
        out = AgentAction(episode=episode, step=step, action=action)
        out.header.stamp = self.get_clock().now().to_msg()
        self._output(robot).publish(out)  # an input came, so it is matched: advertised by now or here
        self.sent += 1

    def close(self) -> None:
        if self.learner is not None:
            self.learner.stop()


class Learner:
    """policy learn: SB3's learn() in a thread, on a TopicEnv fed by the node's callbacks."""

    def __init__(self, node: AgentNode, p: dict) -> None:
        from ..rl import algorithm_name, load_rl_config

        self.node = node
        self.task = node.info.name
        self.algo = algorithm_name(self.task, continuous=not node.discrete)
        overrides = {"episodes": int(p["episodes"]) or None}
        if int(p["learning_starts"]) >= 0:
            overrides["learning_starts"] = int(p["learning_starts"])
        try:
            self.cfg = load_rl_config(self.algo, p["rl_config"] or None, task=self.task, **overrides)
        except (OSError, ValueError) as exc:
            raise NodeError(f"RL config: {exc}") from None
        self.episodes = int(self.cfg["episodes"])
        self.seed = int(p["seed"])
        self.out = Path(p["out"])
        self.save_every = int(p["save_every"])
        self.log_every = max(1, int(p["log_every"]))
        self.use_hidden = bool(p["observe_hidden"])
        self.overlap = bool(p["overlap_training"])
        self.save_buffer = bool(p["save_replay_buffer"])
        self.envs: list = []  # one TopicEnv per robot
        self.model = None
        self.keeper = None  # the PolicyKeeper (kept_policy): policy.zip is its best snapshot
        self.finished = False
        self.thread: threading.Thread | None = None
        self.records: list = []      # (episode id, learnt return, steps, wall time, q, who served it)
        self.labels: dict = {}       # (robot, episode id) -> oracle return (TrajectoryReturn)
        self.lock = threading.Lock()
        self.done = threading.Event()
        self.t0 = time.monotonic()
        self.outcome = "not started"
        self.learn_seconds = 0.0
        self.source = ""
        self.checkpoint = str(p["checkpoint"])  # the model to relabel with once it is served
        self.relabelled = self.checkpoint        # the model the replay buffer's labels are from
        self.catch_up_left = 0                   # catch-up gradient steps still to take on it
        node.get_logger().info(f"learning {self.algo} on {self.task} for {self.episodes} episodes, "
                               f"seed {self.seed}, output {self.out}")

    # -- node thread -------------------------------------------------------------------------------
    def on_reward_step(self, msg: RewardStep, robot: int = 0) -> None:
        self.node.messages_received += 1
        if not self.envs:  # the learner starts at the first step 0 of any robot
            if msg.step != 0 or msg.terminated or msg.truncated:
                return
            self.source = msg.source
            self.start(len(msg.augmented_state) if self.use_hidden else len(msg.state))
        self.envs[robot].put(msg)

    def on_label(self, msg: TrajectoryReturn, robot: int = 0) -> None:
        with self.lock:
            self.labels[(robot, int(msg.episode))] = float(msg.return_value)

    def new_checkpoint(self, value: str) -> str:
        """The `checkpoint` parameter set while running: relabel with it once it is served."""
        from ..mil.checkpoint import checkpoint_paths

        if value and not checkpoint_paths(value)[0].is_file():
            return f"no checkpoint {value}"
        self.checkpoint = str(value)
        return ""

    def start(self, observation_size: int) -> None:
        import gymnasium as gym

        from ..ros.topic_env import TopicEnv

        info = self.node.info
        if self.node.discrete:
            space = gym.spaces.Discrete(info.action_size)
        else:
            space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        # each robot's bridge ends after its share of the episodes (see TopicEnv): the learner
        # stops at the step after the last one, without waiting for an episode that never comes
        n = len(self.node.robots)
        share = -(-self.episodes // n)
        self.envs = [TopicEnv(observation_size, space,
                              lambda e, t, a, i=i: self.node.publish_action(e, t, a, i),
                              use_hidden=self.use_hidden, max_episodes=share, robot=i)
                     for i in range(n)]
        self.thread = threading.Thread(target=self.run, name="learner", daemon=True)
        self.thread.start()

    def stop(self) -> None:
        """Called at shutdown: stop the learner (it saves) and wait for it."""
        for env in self.envs:
            env.stop()
        if self.thread is not None:
            self.thread.join(timeout=60.0)
        steps = sum(e.steps_taken for e in self.envs)
        waited = sum(e.wait_seconds for e in self.envs) / max(len(self.envs), 1)
        split = ""
        if steps and self.learn_seconds:
            split = (f"; per step {1e3 * self.learn_seconds / steps:.2f} ms: waiting for the graph "
                     f"{1e3 * waited / steps:.2f} ms, learning (SB3) {1e3 * (self.learn_seconds - waited) / steps:.2f} ms")
        self.node.get_logger().info(f"learner {self.outcome}; {len(self.records)} episode(s), "
                                    f"{sum(e.skipped for e in self.envs)} message(s) skipped, "
                                    f"{sum(e.broken for e in self.envs)} episode(s) cut short{split}")

    # -- learner thread ----------------------------------------------------------------------------
    def run(self) -> None:
        import torch
        from stable_baselines3.common.monitor import Monitor
        from stable_baselines3.common.vec_env import DummyVecEnv

        from ..rl import EpisodeCurveCallback, make_algorithm
        from ..ros.topic_env import LearnerStopped
        from ..ros.topic_vec_env import ThreadedVecEnv

        torch.set_num_threads(int(self.cfg.get("threads", 1)))
        log = self.node.get_logger()
        try:
            monitored = [lambda env=env: Monitor(env) for env in self.envs]
            vec = ThreadedVecEnv(monitored) if len(monitored) > 1 else DummyVecEnv(monitored)
            self.model = make_algorithm(vec, self.algo, self.cfg, self.node.info.episode_length, seed=self.seed,
                                        image_shape=self.node.info.image_shape)
            if self.overlap and len(self.envs) == 1:  # a fleet's envs step in threads of their own
                self.model.overlap_training = True
                self.envs[0].after_publish = self.model.train_pending
            from ..rl.training import make_keeper

            self.keeper = make_keeper(self.cfg)
            callback = EpisodeCurveCallback(max_episodes=self.episodes, on_episode=self.on_episode,
                                            between_steps=self.between_steps, keeper=self.keeper)
            t0 = time.monotonic()
            try:
                self.model.learn(total_timesteps=self.episodes * self.node.info.episode_length, callback=callback)
            finally:
                self.learn_seconds = time.monotonic() - t0
            self.outcome = f"finished {self.episodes} episodes"
            self.finished = True
            self.wait_for_labels()
        except LearnerStopped:
            self.outcome = "stopped by shutdown"
        except Exception as exc:  # noqa: BLE001 - a learner failure must not lose the policy
            self.outcome = f"failed: {exc!r}"
            log.error(f"learner failed: {exc!r}")
        finally:
            if self.model is not None:
                self.save()
            self.done.set()
            if self.node.exit_code is None:
                self.node.exit_code = 0 if not self.outcome.startswith("failed") else 1

    #: catch-up gradient steps taken between two actions: env_sim re-asks for an action after its
    #: action_timeout (5 s) and gives the episode up after 3 tries, so a catch-up of 10000 steps
    #: (25-75 s) is spread over the following steps, ~0.3-0.6 s between two actions
    CATCH_UP_CHUNK = 200

    def between_steps(self) -> None:
        """Learner thread, between two steps: relabel on a new model, then catch up in chunks."""
        self.relabel_if_served()
        if self.catch_up_left > 0 and self.model is not None:
            from ..rl.replay_relabel import catch_up

            try:
                done = catch_up(self.model, min(self.catch_up_left, self.CATCH_UP_CHUNK))
            except Exception as exc:  # noqa: BLE001 - a failed refit must not stop the learner
                self.node.get_logger().error(f"catch-up on {self.relabelled} stopped: {exc!r}")
                done = 0
            self.catch_up_left = self.catch_up_left - done if done else 0
            if self.catch_up_left == 0:
                self.node.get_logger().info(f"caught up on {Path(self.relabelled).name}")

    def relabel_if_served(self) -> None:
        """Learner thread, between steps: relabel the replay buffer with `checkpoint` once a
        robot's current episode is served by it (RewardStep.source = its file name); the agent
        then catches up on it (`catch_up_steps` gradient steps, `CATCH_UP_CHUNK` between two
        actions: `between_steps`)."""
        wanted = self.checkpoint
        if not wanted or wanted == self.relabelled or self.model is None:
            return
        from ..mil.checkpoint import checkpoint_paths

        name = checkpoint_paths(wanted)[0].with_suffix("").name
        if name not in {env.source for env in self.envs}:
            return  # the reward model serves it from its next episode start
        from ..mil import CheckpointError, OnlineRewardModel
        from ..rl.config import trust_settings
        from ..rl.replay_relabel import relabel_replay_buffer

        self.relabelled = wanted
        log = self.node.get_logger()
        try:
            d = self.node.info.state_size
            stepper = OnlineRewardModel.from_checkpoint(wanted, task=self.task, state_size=d)
            width = self.model.observation_space.shape[0]
            if self.use_hidden and width != d + stepper.served_size:
                raise ValueError(f"it serves {stepper.served_size} hidden values, the agent observes {width - d}")
            t0 = time.monotonic()
            n = relabel_replay_buffer(self.model.replay_buffer, stepper, d)
            steps = self.catch_up_left = int(trust_settings(self.cfg)["catch_up_steps"])
        except (CheckpointError, ValueError, OSError) as exc:
            log.error(f"replay buffer not relabelled with {wanted}: {exc}")
            return
        if self.keeper is not None:  # a policy is kept with the model it acted on
            self.keeper.retag(wanted, self.model)
        log.info(f"replay buffer relabelled with {name}: {n} transitions in {time.monotonic() - t0:.1f} s; "
                 f"up to {steps} catch-up gradient steps follow, {self.CATCH_UP_CHUNK} between two actions")

    def on_episode(self, rec, info: dict) -> None:
        key = (info.get("robot", 0), info.get("episode_id", -1))
        self.records.append((key, rec.learnt_return, rec.steps, time.monotonic() - self.t0, rec.q,
                             str(info.get("source", ""))))
        n = len(self.records)
        if n % self.log_every == 0 or n == self.episodes:
            last = self.records[-self.log_every:]
            with self.lock:
                oracle = [self.labels[e] for e, *_ in last if e in self.labels]
            eps = getattr(self.model, "exploration_rate", None)
            self.node.get_logger().info(
                f"episode {n}/{self.episodes}: mean learnt return {np.mean([r[1] for r in last]):.3f}"
                + (f", mean oracle return {np.mean(oracle):.3f}" if oracle else "")
                + (f", epsilon {eps:.3f}" if eps is not None else "")
                + f", {sum(r[2] for r in self.records) / max(self.records[-1][3], 1e-9):.0f} steps/s")
        if self.save_every and n % self.save_every == 0 and n < self.episodes:
            self.save()

    def wait_for_labels(self, timeout: float = 5.0) -> None:
        """Finished: the last episodes' oracle labels may still be on their way (a labeller
        publishes an episode's return once its final step has arrived, while the learner ends on
        that same step). Wait up to `timeout` s for the label of every episode of a robot whose
        label topic has a publisher, so that the saved curve has them."""
        labelled = {i for i, sub in enumerate(self.node.label_subs) if sub.get_publisher_count() > 0}
        deadline = time.monotonic() + timeout
        while True:
            with self.lock:
                missing = [key for key, *_ in self.records if key[0] in labelled and key not in self.labels]
            if not missing:
                return
            if time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        self.node.get_logger().warning(f"saving without the oracle label of {len(missing)} episode(s) "
                                       f"(none arrived within {timeout:.0f} s of the last step)")

    def save(self) -> None:
        from ..rl import LearningCurve, save_agent
        from ..rl.training import EpisodeRecord

        with self.lock:
            labels = dict(self.labels)
        # one robot: the curve's episode column is env_sim's episode id; a fleet: the order in
        # which its episodes ended
        fleet = len(self.node.robots) > 1
        curve = LearningCurve([EpisodeRecord(n if fleet else key[1], labels.get(key, float("nan")), g, steps, wall,
                                             q=dict(q))
                               for n, (key, g, steps, wall, q, _) in enumerate(self.records)])
        report = None
        if self.keeper is not None:  # the labeller's judgements arrive after their episodes
            for n, (key, *_) in enumerate(self.records):
                self.keeper.set_judged(n, labels.get(key, float("nan")))
            from ..rl.training import end_of_run

            _, report = end_of_run(curve, self.model, self.keeper)
        model_check = self.model_check(labels) if self.finished else None
        save_agent(self.model, curve, self.out, {
            "task": self.task, "algorithm": self.algo, "seed": self.seed, "reward_source": self.source,
            "reward": ("oracle" if self.use_hidden else "oracle-no-hidden") if self.source == "oracle" else "model",
            "episodes": self.episodes, "episodes_done": len(self.records), "observe_hidden": self.use_hidden,
            "outcome": self.outcome, "config": self.cfg, "robots": self.node.robots,
            **({"model_check": model_check.to_dict()} if model_check else {})},
            keeper=self.keeper, collapse=report)
        if self.save_buffer:
            self.model.save_replay_buffer(self.out / "replay_buffer.pkl")
        self.node.get_logger().info(f"saved {self.out}/policy.zip after {len(self.records)} episode(s)")
        if self.finished and report is not None:
            self.node.get_logger().info(report.summary())
        if model_check is not None:
            line = model_check.summary().replace("by the oracle", "by the labeller")
            if model_check.passed:
                self.node.get_logger().info(line)
            else:  # the repair: label the agent's own episodes and retrain (docs/guide/loop.md)
                self.node.get_logger().warning(f"{line}; label its own episodes and retrain: "
                                               f"launch_scripts/loop.launch.yaml, or nmrm loop")

    def model_check(self, labels: dict):
        """The reward model against the labeller's returns on the agent's last 50 episodes
        (`rl.model_check`: is the agent where the model is wrong?), when every one of them was
        served by the model of `checkpoint` (RewardStep.source names it, as the reward_model node
        does by default) and labelled; else None (no checkpoint given, the oracle served, another
        model, a label missing)."""
        if not self.checkpoint or self.source == "oracle":
            return None
        from pathlib import Path

        from ..rl.model_check import model_check_of_run

        last = self.records[-50:]
        if not last or any(r[5] != Path(self.checkpoint).with_suffix("").name or r[0] not in labels for r in last):
            return None
        return model_check_of_run(self.checkpoint, [r[1] for r in last], [labels[r[0]] for r in last])


def main(args=None) -> int:
    return AgentNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
