"""A gymnasium Env that is a bridge to the graph's topics, so SB3's own `learn()` drives learning
through ROS (the agent node's `policy:=learn`).

The node's subscription callback feeds every RewardStep into `put()` (any thread); `reset()` and
`step()` (the learner's thread) wait for the messages they need:

- `reset()` waits for step 0 of a new episode; observation = its augmented state (or state).
- `step(a_t)` publishes AgentAction(e, t, a_t) and waits for RewardStep(e, t + 1). The reward
  of the transition is r'_t, from RewardStep(e, t) (the reward model computes it from s_t, before
  the action): the same transitions as `nmrm_ros.rl.wrappers` gives without ROS. A repeat of
  (e, t) (env_sim re-published after an action timeout) makes it send the same action again.
  If step 0 of another episode arrives instead (the episode was cut short), the step returns
  `truncated=True` with `info["broken"]` and the message starts the next `reset()`.

Episode seeds belong to env_sim (`seed + e`); a seed passed to `reset()` is ignored. After
`max_episodes` complete episodes, `reset()` and `step()` return a zero observation at once
instead of waiting (SB3's VecEnv resets right after the last step, and the learner takes one more
step before its callback stops it; that step is not stored).
Plain Python: messages are duck-typed (episode, step, state, augmented_state, reward,
terminated, truncated); the node passes a `publish_action(episode, step, action)` callable.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Callable

import gymnasium as gym
import numpy as np


class LearnerStopped(Exception):
    """The node is shutting down: the learner leaves `learn()` and saves what it has."""


class TopicEnv(gym.Env):
    """observation_size: length of what is observed; action_space: the task's; use_hidden: observe
    RewardStep.augmented_state (else .state); timeout: seconds without any message before
    TimeoutError (0 = wait for ever); robot: its index in a fleet (reported in the infos)."""

    metadata = {"render_modes": []}

    def __init__(self, observation_size: int, action_space: gym.Space,
                 publish_action: Callable[[int, int, list], None], use_hidden: bool = True,
                 timeout: float = 0.0, max_episodes: int = 0, robot: int = 0) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(observation_size,), dtype=np.float32)
        self.action_space = action_space
        self.publish_action = publish_action
        self.use_hidden = use_hidden
        self.timeout = float(timeout)
        self.max_episodes = int(max_episodes)
        self.robot = int(robot)  # index of this bridge in a fleet (in every info as "robot")
        self.episodes_done = 0
        self.stop_event = threading.Event()
        self.inbox: queue.Queue = queue.Queue()
        self._held = None          # a step 0 that arrived while an episode was still running
        self.episode: int | None = None
        self.source = ""
        self.t = 0
        self._pending = 0.0
        self._return = 0.0
        self._last_obs: np.ndarray | None = None
        self._action: list | None = None
        #: messages that were not the awaited one (stale, from another episode...), and cut episodes
        self.skipped = 0
        self.broken = 0
        #: seconds the learner spent waiting for the graph (in step/reset) and the steps taken: the
        #: rest of its time is the learner's own (SB3: acting, storing, gradient steps)
        self.wait_seconds = 0.0
        self.steps_taken = 0
        #: called after each action is published, before waiting for the answer (or None)
        self.after_publish: Callable[[], None] | None = None

    # -- feeding (node thread) ---------------------------------------------------------------------
    def put(self, msg) -> None:
        self.inbox.put(msg)

    def stop(self) -> None:
        self.stop_event.set()

    # -- gymnasium (learner thread) ----------------------------------------------------------------
    def _next(self):
        waited = time.monotonic()
        while True:
            if self.stop_event.is_set():
                raise LearnerStopped()
            try:
                msg = self.inbox.get(timeout=0.1)
                self.wait_seconds += time.monotonic() - waited
                return msg
            except queue.Empty:
                if self.timeout and time.monotonic() - waited > self.timeout:
                    raise TimeoutError(f"no RewardStep for {self.timeout:.0f} s") from None

    def _observe(self, msg) -> np.ndarray:
        values = msg.augmented_state if self.use_hidden else msg.state
        obs = np.asarray(values, dtype=np.float32)
        if obs.shape != self.observation_space.shape or not np.all(np.isfinite(obs)):
            raise ValueError(f"observation of shape {obs.shape} (finite: {np.all(np.isfinite(obs))}), "
                             f"expected {self.observation_space.shape}")
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if self._after_last_episode():
            return np.zeros(self.observation_space.shape, np.float32), {"after_last_episode": True}
        while True:
            msg, self._held = (self._held, None) if self._held is not None else (self._next(), None)
            if msg.step == 0 and msg.episode != self.episode and not (msg.terminated or msg.truncated):
                break
            self.skipped += 1
        self.episode, self.t = int(msg.episode), 0
        self.source = str(getattr(msg, "source", ""))  # who serves this episode (RewardStep.source)
        self._pending, self._return = float(msg.reward), 0.0
        self._last_obs = self._observe(msg)
        return self._last_obs, {"episode_id": self.episode, "robot": self.robot}

    def _after_last_episode(self) -> bool:
        return bool(self.max_episodes) and self.episodes_done >= self.max_episodes

    def step(self, action):
        if self.episode is None:
            raise RuntimeError("call reset() before step()")
        if self._after_last_episode():  # nothing to send: the learner stops at this step
            return np.zeros(self.observation_space.shape, np.float32), 0.0, False, True, {"after_last_episode": True}
        self._action = [float(x) for x in np.asarray(action, dtype=np.float64).reshape(-1)]
        self.publish_action(self.episode, self.t, self._action)
        if self.after_publish is not None:  # e.g. the learner's gradient step, while the graph works
            self.after_publish()
        while True:
            msg = self._next()
            if msg.episode == self.episode and msg.step == self.t:
                self.publish_action(self.episode, self.t, self._action)  # re-published observation
                continue
            if msg.episode == self.episode and msg.step == self.t + 1:
                break
            if msg.step == 0 and msg.episode != self.episode:
                self._held = msg
                self.broken += 1
                self.episodes_done += 1
                reward = self._pending
                self._return += reward
                return self._last_obs, reward, False, True, {
                    "broken": True, "episode_id": self.episode, "robot": self.robot, "learnt_reward": reward,
                    "learnt_return": self._return, "source": self.source}
            self.skipped += 1
        reward = self._pending
        self._return += reward
        self.t += 1
        self.steps_taken += 1
        self._pending = float(msg.reward)
        self._last_obs = self._observe(msg)
        info = {"episode_id": self.episode, "robot": self.robot, "learnt_reward": reward}
        if msg.terminated or msg.truncated:
            info["learnt_return"] = self._return
            info["source"] = self.source  # who served the episode (a model is swapped at step 0 only)
            self.episodes_done += 1
        return self._last_obs, reward, bool(msg.terminated), bool(msg.truncated), info
