"""Episodes of a trained agent, for a dataset's pool (the paper's recycled oracle-agent episodes),
and a saved policy that rolls out the pool of a return-screened dataset.

The dataset code (`nmrm_ros.datasets`) knows no agents: it takes what this module builds
(`AgentEpisodes` for Lunar Lander's pool, `load_screening_policy` for return bins; `nmrm dataset
... --policy` builds them).

The paper's Lunar Lander dataset is screened from the episodes of its oracle-trained SAC agents
(App. D.2): goal-directed trajectories, with the agents' own ways of landing and taking off. A pool
of scripted episodes alone leaves those ways unseen, and an agent trained on a model of it finds
them (issue 31: a CSC agent resting on one leg before both touched, then taking off after 45-49 steps
on the pad, paid in full). `rollout_agent` rolls out a saved agent (`policy.zip` with its
`agent.json`), acting as it explores (SB3's predict(deterministic=False)), and observing what it
observed in training: the oracle's hidden state appended (reward "oracle") or the plain state
("oracle-no-hidden"). An agent of a reward model is refused: its observation needs that model.

`early` (agents of reward "oracle" only): in a seeded half of the episodes the appended hidden state
is raised by an integer drawn from 1..early, so that an agent that waits for a count (Lunar Lander:
50 steps on the pad) acts on it `early` steps or fewer too soon: the near misses a model must tell
apart from the real thing, in the agent's own way of flying.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: what a pool's agent may have learnt from: its observation can be rebuilt without a model
AGENT_REWARDS = ("oracle", "oracle-no-hidden")


def rollout_agent(policy: str | Path, task: str, episodes: int, seed: int = 0, early: int = 0) -> list:
    """`episodes` episodes of the agent saved at `policy` (a policy.zip), episode e reset with seed
    `seed + e`, its action sampling seeded with `seed`. Returns a list of (states (L + 1, d)
    float32, actions (L, A) float32, terminated bool), the states without anything appended, as
    `rollout_lunar_lander` returns them; `early`: see the module's docstring. ValueError (one line)
    for a policy that cannot be loaded, of another task, or of a reward model."""
    from ..tasks import task_info
    from .evaluation import load_agent
    from .wrappers import make_reward_env

    model, meta = load_agent(policy)
    if meta.get("task") and meta["task"] != task:
        raise ValueError(f"agent {policy} was trained on task {meta['task']!r}, not {task!r}")
    reward = meta.get("reward")
    if reward not in AGENT_REWARDS:
        raise ValueError(f"agent {policy} learnt from reward {reward!r}: a pool's agent must have learnt "
                         f"from the oracle ({' or '.join(AGENT_REWARDS)}; agent.json says what)")
    env = make_reward_env(task, reward, seed=seed, continuous=meta.get("algorithm") == "sac")
    if env.observation_space.shape != model.observation_space.shape:
        raise ValueError(f"agent {policy} observes {model.observation_space.shape}, the {reward} env "
                         f"gives {env.observation_space.shape}")
    if early < 0 or (early and reward != "oracle"):
        raise ValueError(f"early must be >= 0, and only an agent that observes the oracle's hidden state "
                         f"can be told it early (this one learnt from {reward!r})")
    model.set_random_seed(seed)
    rng = np.random.default_rng(seed)
    size = task_info(task).state_size
    out = []
    try:
        for e in range(episodes):
            shift = np.zeros(model.observation_space.shape, np.float32)
            if early and rng.random() < 0.5:
                shift[size:] = rng.integers(1, early + 1)
            obs, _ = env.reset(seed=seed + e)
            states, actions = [np.asarray(obs[:size], np.float32)], []
            while True:
                action = model.predict(obs + shift, deterministic=False)[0]
                obs, _, terminated, truncated, _ = env.step(action)
                states.append(np.asarray(obs[:size], np.float32))
                actions.append(np.asarray(action, np.float32).reshape(-1))
                if terminated or truncated:
                    break
            out.append((np.asarray(states), np.asarray(actions), bool(terminated)))
    finally:
        env.close()
    return out


class AgentEpisodes:
    """A saved agent's episodes for a screened pool (`datasets.screen_lunar_lander(agent=...)`):
    `rollout(task, n, seed, early)` as `rollout_agent`; str() is its policy path (the dataset's meta)."""

    def __init__(self, policy: str | Path) -> None:
        self.policy = str(policy)

    def __str__(self) -> str:
        return self.policy

    def rollout(self, task: str, episodes: int, seed: int = 0, early: int = 0) -> list:
        return rollout_agent(self.policy, task, episodes, seed=seed, early=early)


class SavedPolicy:
    """`policy(state) -> action` of a saved SB3 policy, acting as it explores; str() is its path."""

    def __init__(self, path: str, model) -> None:
        self.path, self.model = path, model

    def __str__(self) -> str:
        return self.path

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.model.predict(np.asarray(obs, np.float32), deterministic=False)[0]


def load_screening_policy(path: str, task: str, seed: int = 0) -> "SavedPolicy":
    """`policy(state) -> action` of a saved Stable-Baselines3 policy (`nmrm rl train`'s
    policy.zip) that observes the task's plain states, acting as it explores (SB3's
    predict(deterministic=False)). ValueError (one line) if it cannot be loaded or observes
    anything else (e.g. a reward model's augmented state)."""
    from ..tasks import task_info
    from .evaluation import load_agent

    model, meta = load_agent(path)
    if meta.get("task") and meta["task"] != task:
        raise ValueError(f"policy {path} was trained on task {meta['task']!r}, not {task!r}")
    size, want = model.observation_space.shape, (task_info(task).state_size,)
    if size != want:
        raise ValueError(f"policy {path} observes {size[0]} values and {task} states have {want[0]}: "
                         f"screening needs a policy of plain states (nmrm rl train --reward oracle-no-hidden)")
    model.set_random_seed(seed)
    return SavedPolicy(str(path), model)
