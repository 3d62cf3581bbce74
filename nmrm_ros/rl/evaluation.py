"""Judging an agent by the oracle (post hoc, as the paper does): the greedy policy's oracle return
on fixed episode seeds, beside a uniform-random policy's on the same seeds."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..mil.served_state import DEFAULT_SERVED_STATE

#: default first episode seed of evaluations: far from the training seeds (0, 1, 2... + e)
EVAL_SEED = 10**8


@dataclass
class EvaluationResult:
    """Oracle returns (episodes,) of the greedy policy and of a random policy on the same seeds,
    and the learnt returns of the same episodes (what the reward the agent learnt on paid them;
    for an oracle reward, the oracle's)."""

    returns: np.ndarray
    random_returns: np.ndarray
    reward: str
    learnt_returns: np.ndarray | None = None
    random_learnt_returns: np.ndarray | None = None

    @staticmethod
    def _ms(v: np.ndarray) -> tuple[float, float]:
        return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0

    def summary(self) -> str:
        m, s = self._ms(self.returns)
        rm, rs = self._ms(self.random_returns)
        text = (f"oracle return over {len(self.returns)} episodes: policy {m:.3f} ± {s:.3f} (SEM), "
                f"random policy {rm:.3f} ± {rs:.3f}")
        if self.reward == "model" and self.learnt_returns is not None:
            lm, ls = self._ms(self.learnt_returns)
            text += f"; the model paid the policy {lm:.3f} ± {ls:.3f}"
            if self.random_learnt_returns is not None:
                text += f", the random policy {self._ms(self.random_learnt_returns)[0]:.3f}"
            gap = lm - m
            text += f" (model - oracle: {gap:+.3f})"
        return text


def load_agent(policy: str | Path):
    """(SB3 model, agent.json metadata or {}) of a saved policy .zip."""
    from stable_baselines3 import DQN, SAC

    policy = Path(policy)
    if not policy.is_file():
        raise ValueError(f"no policy file {policy}")
    meta_file = policy.with_name("agent.json")
    meta = json.loads(meta_file.read_text()) if meta_file.is_file() else {}
    algo = meta.get("algorithm")
    errors = []
    for cls in ((DQN,) if algo == "dqn" else (SAC,) if algo == "sac" else (DQN, SAC)):
        try:
            return cls.load(policy, device="cpu"), meta
        except Exception as exc:  # noqa: BLE001 - try the other algorithm, then report
            errors.append(f"{cls.__name__}: {exc}")
    raise ValueError(f"cannot load policy {policy}: {'; '.join(errors)}")


def _reward_kind(model, task: str, checkpoint, meta: dict, oracle: str = "") -> tuple[str, object]:
    from ..oracles import make_oracle
    from ..tasks import task_info

    if checkpoint is not None:
        return "model", checkpoint
    if meta.get("reward"):
        if meta["reward"] == "model" and not meta.get("checkpoint"):
            raise ValueError("the policy was trained on a model's reward; give its checkpoint")
        return meta["reward"], meta.get("checkpoint")
    size = model.observation_space.shape[0]
    state = task_info(task).state_size
    if size == state:
        return "oracle-no-hidden", None
    if size == state + make_oracle(task, oracle).hidden_size:
        return "oracle", None
    raise ValueError(f"the policy observes {size} values; task {task} states have {state}: give the "
                     f"checkpoint of the reward model it was trained with")


def served_state_of(model, task: str, checkpoint, meta: dict) -> str:
    """What of the reward model's state a policy observes: agent.json's `served_state`, else the
    checkpoint's own (its training config's) if the policy's observation has its size, else (a
    policy saved before it was recorded) inferred from its observation size: [h', c'] or h'."""
    if meta.get("served_state"):  # "hc": the raw [h', c'], as policies of 2026-12-02 named it
        return {"hc": "h_c"}.get(meta["served_state"], meta["served_state"])
    from ..mil import load_checkpoint
    from ..mil.served_state import served_size
    from ..tasks import task_info

    reward_model, checkpoint_meta = load_checkpoint(checkpoint, task=task)
    k = reward_model.hidden_size
    extra = model.observation_space.shape[0] - task_info(task).state_size
    own = checkpoint_meta.served_state
    if extra == served_size(k, own, attention=reward_model.uses_attention):
        return own
    if extra == 2 * k:
        return "h_c"
    if extra == k:
        return "h"
    raise ValueError(f"the policy observes {extra} values beyond the state; the reward model serves "
                     f"{2 * k} ([h', c']) or {k} (h' only)")


def evaluate_agent(policy, task: str, checkpoint: str | Path | None = None, episodes: int = 50,
                   seed: int = EVAL_SEED, reward: str | None = None, env=None,
                   oracle: str | None = None) -> EvaluationResult:
    """Run the greedy policy (`policy`: a .zip path or an SB3 model) for `episodes` episodes with
    episode seeds seed, seed + 1, ... and return its oracle returns and a random policy's.

    The observation is built as in training: with `checkpoint` the model's hidden state, else the
    reward kind recorded in the policy's agent.json (or inferred from its observation size).
    `env`: evaluate on this wrapped env instead (its `info` must carry "oracle_return").
    `oracle`: a user's oracle function that judges (default: agent.json's, else the task's).
    """
    from .wrappers import make_reward_env

    meta = {}
    model = policy
    if isinstance(policy, (str, Path)):
        model, meta = load_agent(policy)
    if meta.get("task") and meta["task"] != task:
        raise ValueError(f"the policy was trained on task {meta['task']!r}, not {task!r}")
    oracle = (meta.get("oracle") or "") if oracle is None else oracle
    if reward is None:
        reward, checkpoint = _reward_kind(model, task, checkpoint, meta, oracle)
    if env is None:
        served = served_state_of(model, task, checkpoint, meta) if reward == "model" else DEFAULT_SERVED_STATE
        env = make_reward_env(task, reward, checkpoint if reward == "model" else None, seed=seed,
                              served=served, oracle=oracle, observe=meta.get("observe", "state"))
    if env.observation_space.shape != model.observation_space.shape:
        raise ValueError(f"the policy observes {model.observation_space.shape}, the {reward} env gives "
                         f"{env.observation_space.shape}")
    returns, learnt = run_episodes(env, episodes, seed, lambda obs: model.predict(obs, deterministic=True)[0])
    random_returns, random_learnt = run_episodes(env, episodes, seed, random_policy(env.action_space, seed))
    return EvaluationResult(returns, random_returns, reward, learnt, random_learnt)


def random_policy(space, seed: int):
    """obs -> a uniformly random action of `space` (Discrete or Box), from a generator of `seed`."""
    rng = np.random.default_rng(seed)
    if hasattr(space, "n"):
        return lambda obs: int(rng.integers(space.n))
    return lambda obs: rng.uniform(space.low, space.high).astype(np.float32)


def run_episodes(env, episodes: int, seed: int, act) -> tuple[np.ndarray, np.ndarray]:
    """(oracle returns, learnt returns) (episodes,) of `episodes` episodes of a reward env
    (`wrappers.make_reward_env`) under `act` (obs -> action), episode seeds seed, seed + 1, ...;
    a learnt return the env does not report is NaN."""
    returns, learnt = [], []
    obs, _ = env.reset(seed=seed)
    while len(returns) < episodes:
        obs, _, terminated, truncated, info = env.step(act(obs))
        if terminated or truncated:
            returns.append(info["oracle_return"])
            learnt.append(info.get("learnt_return", np.nan))
            obs, _ = env.reset()
    return np.asarray(returns), np.asarray(learnt)
