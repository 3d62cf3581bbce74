"""gymnasium wrappers that give a rewardless task env a non-Markovian reward (paper Sec. 3.3, App. E).

A wrapper tracks one hidden state per episode and steps it with every state the env returns:

    reset():  s_0            -> (r_0, h_1) = stepper.step(s_0); observation [s_0, h_1]
    step(a_t): s_{t+1}       -> reward r_t (computed from s_t, as R(s_t, a_t, h_{t+1}) is);
                                (r_{t+1}, h_{t+2}) = stepper.step(s_{t+1}); observation [s_{t+1}, h_{t+2}]

so the agent always observes the hidden state *after* seeing the current state (the paper's
Figure 2 order), exactly as the reward_model node publishes RewardStep.augmented_state. The
stepper's output on the final observation s_T gives the terminal observation; its reward belongs to
no transition. The same rule holds in the ROS graph, so a wrapper and a graph with the same seeds
give the same transitions.

Every wrapper puts the oracle's reward of the transition in `info["oracle_reward"]` (and
`info["learnt_reward"]`), and at the end of an episode `info["oracle_return"]` and
`info["learnt_return"]`, so that any run can be judged by the oracle post hoc, as the paper does;
an oracle with reward components (Lunar Lander's pad, no_contact, hover, shaping) adds the
episode's sum of each in `info["oracle_components"]` (the paper's Figure 10).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import gymnasium as gym
import numpy as np

from ..oracles import Oracle, make_oracle

REWARD_KINDS = ("model", "oracle", "oracle-no-hidden")
#: what the agent observes beside the served (or the oracle's hidden) state: the task's state
#: (e.g. a camera image), or its privileged state (e.g. the true position behind the image: for
#: a pixel task, an agent of vector states while the reward model sees only pixels)
OBSERVE = ("state", "privileged")


class HiddenStateStepper(Protocol):
    """What a wrapper steps: `nmrm_ros.mil.OnlineRewardModel` or `nmrm_ros.oracles.OracleTracker`."""

    def reset(self) -> None: ...

    def step(self, state: np.ndarray) -> tuple[float, np.ndarray]: ...


class EpisodeSeeds(gym.Wrapper):
    """Reset episode e with seed `seed + e`, as the env_sim node does.

    `reset(seed=s)` restarts the count at s (e = 0); `reset()` without a seed moves to the next
    episode. This makes every episode reproducible on its own, and a wrapper run see the same
    episodes as a graph whose env_sim has `seed:=s`.
    """

    def __init__(self, env: gym.Env, seed: int = 0) -> None:
        super().__init__(env)
        self.base_seed = int(seed)
        self.episode = -1

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.base_seed, self.episode = int(seed), -1
        self.episode += 1
        return self.env.reset(seed=self.base_seed + self.episode, options=options)


class NonMarkovianRewardWrapper(gym.Wrapper):
    """Replace the env's reward by a stepper's reward; optionally append its hidden state.

    env: a rewardless task env (`nmrm_ros.tasks.make_env`); stepper: gives (r_t, h_{t+1}) per state;
    task: the task (or an `Oracle`) whose oracle judges the run (info); augment: observe
    [s_t, h_{t+1}] (else s_t only); hidden_size: size of h (for the observation space); observe:
    "privileged" puts the privileged state (info["privileged"], `privileged_size` values) where
    s_t was in the observation (the stepper still steps with s_t).
    """

    #: the stepper is stepped with the privileged state where there is one (an oracle's tracker)
    stepper_sees_privileged = False

    def __init__(self, env: gym.Env, stepper: HiddenStateStepper, task: str | Oracle, augment: bool,
                 hidden_size: int, observe: str = "state", privileged_size: int = 0) -> None:
        super().__init__(env)
        if observe not in OBSERVE:
            raise ValueError(f"unknown observation {observe!r}; use one of {', '.join(OBSERVE)}")
        if observe == "privileged" and privileged_size < 1:
            raise ValueError("observe privileged: the task has no privileged state")
        self.stepper = stepper
        self.judge = make_oracle(task) if isinstance(task, str) else task
        self.oracle = self.judge.tracker()
        self.augment = augment and hidden_size > 0
        self.observe = observe
        base = env.observation_space
        if observe == "privileged":
            base = gym.spaces.Box(-np.inf, np.inf, (privileged_size,), np.float32)
            self.observation_space = base
        if self.augment:
            low = np.concatenate([base.low, np.full(hidden_size, -np.inf)]).astype(np.float32)
            high = np.concatenate([base.high, np.full(hidden_size, np.inf)]).astype(np.float32)
            self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self._pending = (0.0, 0.0)  # (reward, oracle reward) of the current state s_t
        self._returns = [0.0, 0.0]
        self._states: list = []  # s_0..s_t of the episode in progress (for swap_stepper)
        self._seen: list = []  # what the agent saw of them (`observe`)

    def _consume(self, state: np.ndarray, info: dict) -> np.ndarray:
        """Step both trackers with s_t (the oracle with the privileged state, `info["privileged"]`,
        where the task has one: e.g. the position behind a pixel task's image); remember r_t;
        return the observation."""
        privileged = info.get("privileged", state)
        reward, hidden = self.stepper.step(privileged if self.stepper_sees_privileged else state)
        oracle_reward, _ = self.oracle.step(privileged)
        self._pending = (float(reward), float(oracle_reward))
        self._states.append(np.array(state))  # a copy: an env may reuse its buffer
        self._seen.append(np.array(privileged if self.observe == "privileged" else state))
        return self._observation(self._seen[-1], hidden)

    def _observation(self, state: np.ndarray, hidden: np.ndarray) -> np.ndarray:
        """[what the agent sees of s_t (`observe`), h_{t+1}]."""
        if not self.augment:
            return np.asarray(state, dtype=np.float32)
        return np.concatenate([np.asarray(state, np.float64), np.asarray(hidden, np.float64)]).astype(np.float32)

    def swap_stepper(self, stepper: HiddenStateStepper) -> np.ndarray:
        """Serve `stepper` from now on: it is reset and stepped over the episode in progress
        (s_0..s_t), so the reward of the next transition and the observation are its own; the
        learnt return so far is recomputed with it. Returns the observation [s_t, h_{t+1}] of
        the current state under the new stepper (the agent must act on it, not on the old one)."""
        if not self._states:
            raise RuntimeError("swap_stepper needs an episode in progress (call reset first)")
        stepper.reset()
        rewards = [stepper.step(s) for s in self._states]
        self.stepper = stepper
        self._returns[0] = float(sum(r for r, _ in rewards[:-1]))
        self._pending = (float(rewards[-1][0]), self._pending[1])
        return self._observation(self._seen[-1], rewards[-1][1])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        state, info = self.env.reset(seed=seed, options=options)
        self.stepper.reset()
        self.oracle.reset()
        self._returns = [0.0, 0.0]
        self._states, self._seen = [], []
        return self._consume(state, info), info

    def step(self, action):
        state, _, terminated, truncated, info = self.env.step(action)
        reward, oracle_reward = self._pending
        self._returns[0] += reward
        self._returns[1] += oracle_reward
        obs = self._consume(state, info)
        info = dict(info, learnt_reward=reward, oracle_reward=oracle_reward)
        if terminated or truncated:
            info.update(learnt_return=self._returns[0], oracle_return=self._returns[1])
            if hasattr(self.judge, "label_components"):  # e.g. Lunar Lander's four reward terms
                states = np.stack(self._states[:-1])[None]
                parts = self.judge.label_components(states, np.array([states.shape[1]]))
                info["oracle_components"] = {k: float(v.sum()) for k, v in parts.items()}
        return obs, reward, terminated, truncated, info


class RewardModelWrapper(NonMarkovianRewardWrapper):
    """Observation [s_t, served_{t+1}] and reward r'_t from a trained MIL model, stepped online.

    model: a `MILRewardModel` or a checkpoint path (its task must be the env's); served: what of
    the LSTM's state is observed, "h_tanh_c" ([h', tanh c']), "h_c" ([h', c']) or "h" (h' only,
    the paper's choice; `nmrm_ros.mil.served_state`); None: the checkpoint's own (its training
    config's served_state), else h_tanh_c.
    """

    def __init__(self, env: gym.Env, model, task: str | None = None,
                 served: str | None = None, oracle: str = "", observe: str = "state") -> None:
        from ..mil import OnlineRewardModel
        from ..mil.served_state import DEFAULT_SERVED_STATE

        if isinstance(model, (str, Path)):
            online = OnlineRewardModel.from_checkpoint(model, task=task, served=served)
            task = task or online.task
        else:
            online = OnlineRewardModel(model, served=served or DEFAULT_SERVED_STATE)
        if task is None:
            raise ValueError("RewardModelWrapper needs the task (for the oracle's judgement)")
        if online.input_size != env.observation_space.shape[0]:
            raise ValueError(f"the model takes states of size {online.input_size}, the env gives "
                             f"{env.observation_space.shape[0]}")
        served = online.served
        judge = make_oracle(task, oracle) if oracle else task
        super().__init__(env, online, judge, augment=True, hidden_size=online.served_size, observe=observe,
                         privileged_size=_privileged_size(task))
        self.served = served
        self.task = task

    def swap_model(self, model) -> np.ndarray:
        """Serve `model` (a `MILRewardModel`, `MILEnsemble` or checkpoint path of the same task)
        from now on, with the same served state, which must have the same size (the observation
        space does not change); the episode in progress is re-stepped (`swap_stepper`).
        Returns the current observation under the new model."""
        from ..mil import OnlineRewardModel

        if isinstance(model, (str, Path)):
            online = OnlineRewardModel.from_checkpoint(model, task=self.task, served=self.served)
        else:
            online = OnlineRewardModel(model, served=self.served)
        if online.served_size != self.stepper.served_size or online.input_size != self.stepper.input_size:
            raise ValueError(f"the new model serves {online.served_size} values for states of size "
                             f"{online.input_size}; the agent observes {self.stepper.served_size} for "
                             f"{self.stepper.input_size}")
        return self.swap_stepper(online)


class OracleRewardWrapper(NonMarkovianRewardWrapper):
    """The paper's baselines: the oracle's reward, with its hidden state appended (`hidden=True`)
    or the raw state only (`hidden=False`). The oracle's hidden state is appended as it is
    (unscaled, e.g. Timer's time index 1..100), as in the paper."""

    stepper_sees_privileged = True

    def __init__(self, env: gym.Env, task: str, hidden: bool = True, oracle: str = "", observe: str = "state") -> None:
        judge = make_oracle(task, oracle)
        super().__init__(env, judge.tracker(), judge, augment=hidden, hidden_size=judge.hidden_size,
                         observe=observe, privileged_size=_privileged_size(task))


def _privileged_size(task: str) -> int:
    from ..tasks import task_info

    return task_info(task).privileged_size


def make_reward_env(task: str, reward: str, checkpoint: str | Path | None = None,
                    seed: int = 0, continuous: bool = False,
                    served: str | None = None, oracle: str = "", observe: str = "state") -> gym.Env:
    """A task env with episode seeds `seed + e` and the reward of `reward` (one of REWARD_KINDS).

    reward "model" needs `checkpoint` (a MIL checkpoint trained on `task`); `served`: what of the
    model's recurrent state the agent observes (`RewardModelWrapper`); observe: the agent sees the
    task's state or its privileged state beside it (OBSERVE).
    """
    from ..tasks import make_env

    if reward not in REWARD_KINDS:
        raise ValueError(f"unknown reward kind {reward!r}; use one of {', '.join(REWARD_KINDS)}")
    env = EpisodeSeeds(make_env(task, continuous=continuous), seed)
    if reward == "model":
        if checkpoint is None:
            raise ValueError("reward 'model' needs a checkpoint")
        return RewardModelWrapper(env, checkpoint, task=task, served=served, oracle=oracle, observe=observe)
    if checkpoint is not None:
        raise ValueError(f"reward {reward!r} takes no checkpoint")
    return OracleRewardWrapper(env, task, hidden=reward == "oracle", oracle=oracle, observe=observe)
