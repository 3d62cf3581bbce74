"""Training an RL agent on a non-Markovian reward without ROS (gymnasium + stable-baselines3).

`train_agent(task, reward, checkpoint, episodes, seed, out)` builds the wrapped env
(`make_reward_env`), the paper's algorithm for the task (`make_algorithm`), lets SB3's `learn()`
run, and writes into `out/`:

- `policy.zip`: the SB3 model (load with `DoubleDQN.load` / `SplitLRSAC.load`, or SB3's DQN/SAC)
  with the kept policy's weights: the best snapshot of the run (`kept_policy`), and
  `last_policy.zip` beside it when that is not the last one;
- `curve.csv`: one row per episode: episode, oracle_return, learnt_return, steps, wall_time (s),
  oracle_<component> per reward component where the oracle has them (Lunar Lander), and for a
  value-based agent (DQN) q_max and q_spread: the episode's mean over steps of max_a Q(s, a) and of
  max_a Q − min_a Q (a spread near 0 means the network no longer tells actions apart), and
  value_bound: the bound its targets were clipped to at the episode's end (`value_bound`; it
  moves with the rewards in the replay buffer and with the model the loop serves);
- `curve.png`: the oracle and learnt-reward returns per episode;
- `agent.json`: task, reward kind, checkpoint (and its weights' SHA-256), seeds and config (what
  `evaluate_agent` needs), the kept policy and the collapse report (`collapse`).

The run ends with one line (`AgentRun.collapse.summary()`): whether learning collapsed (a late dip,
values beyond the bound the rewards allow) and which policy was kept.
"""

from __future__ import annotations

import csv
import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import TqdmExperimentalWarning

from ..mil.checkpoint import recorded_weights_sha256
from .collapse import CollapseReport, collapse_report
from .kept_policy import PolicyKeeper


CURVE_FIELDS = ("episode", "oracle_return", "learnt_return", "steps", "wall_time")


@dataclass
class EpisodeRecord:
    episode: int
    oracle_return: float
    learnt_return: float
    steps: int
    wall_time: float
    components: dict = field(default_factory=dict)  # the oracle's return per reward component
    q: dict = field(default_factory=dict)  # DQN: {"q_max", "q_spread"} means over the episode's steps, "value_bound"


@dataclass
class LearningCurve:
    """Episodes finished so far, in the order they finished (over every env of a VecEnv)."""

    records: list = field(default_factory=list)

    def final_oracle_return(self, window: int = 50) -> float:
        """Mean oracle return of the last `window` episodes (the paper's end-of-training figure)."""
        return float(np.mean([r.oracle_return for r in self.records[-window:]])) if self.records else float("nan")

    def write_csv(self, path: Path) -> None:
        names = list(next((r.components for r in self.records if r.components), {}))
        q_names = list(next((r.q for r in self.records if r.q), {}))
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(list(CURVE_FIELDS) + [f"oracle_{n}" for n in names] + q_names)
            for r in self.records:
                w.writerow([r.episode, f"{r.oracle_return:.6g}", f"{r.learnt_return:.6g}", r.steps,
                            f"{r.wall_time:.3f}"] + [f"{r.components.get(n, float('nan')):.6g}" for n in names]
                           + [f"{r.q.get(n, float('nan')):.6g}" for n in q_names])

    def plot(self, path: Path, title: str) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        ep = np.array([r.episode for r in self.records])
        fig, ax = plt.subplots(figsize=(6, 3.5))
        for name, values, colour in (("oracle return", [r.oracle_return for r in self.records], "k"),
                                     ("learnt-reward return", [r.learnt_return for r in self.records], "tab:blue")):
            values = np.asarray(values)
            ax.plot(ep, values, color=colour, alpha=0.25, lw=0.8)
            if len(values) >= 20:
                ax.plot(ep[19:], np.convolve(values, np.ones(20) / 20, mode="valid"), color=colour,
                        label=f"{name} (mean of 20)")
            else:
                ax.plot(ep, values, color=colour, label=name)
        ax.set_xlabel("episode")
        ax.set_ylabel("return")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)


class EpisodeCurveCallback(BaseCallback):
    """Records every finished episode's oracle and learnt returns (from the wrappers' `info`) and
    stops learning after `max_episodes` episodes (Lunar Lander's episodes can end early).
    `on_episode(record, info)` is called for each, with the episode's final `info`;
    `between_steps()` before each of SB3's rollouts (after a step's transition is stored and
    trained on, before the agent acts again: e.g. to relabel the replay buffer). `keeper`: the
    `PolicyKeeper` that snapshots the policy and keeps the best (None: keep the last)."""

    def __init__(self, max_episodes: int | None = None, on_episode=None, between_steps=None,
                 keeper: PolicyKeeper | None = None) -> None:
        super().__init__()
        self.curve = LearningCurve()
        self.keeper = keeper
        self.max_episodes = max_episodes
        self.on_episode = on_episode
        self.between_steps = between_steps
        self._steps: np.ndarray | None = None
        self._q_sums: np.ndarray | None = None  # per env: summed max Q and summed spread this episode
        self._stop_next = False
        self._t0 = time.perf_counter()

    def _on_rollout_start(self) -> None:
        if self.between_steps is not None:
            self.between_steps()

    def _on_step(self) -> bool:
        # SB3 calls this after env.step() and before storing the transition: stop at the step
        # *after* the last episode, so that the last episode's final transition is stored too.
        if self._stop_next:
            return False
        dones = self.locals["dones"]
        if self._steps is None:
            self._steps = np.zeros(len(dones), dtype=np.int64)
        self._steps += 1
        self._add_q_values()
        for i, (done, info) in enumerate(zip(dones, self.locals["infos"])):
            if not done or info.get("after_last_episode"):  # a topic bridge with no episode left
                continue
            q = {}
            bound = value_bound_high(self.model)
            if self._q_sums is not None:
                q = {"q_max": float(self._q_sums[i, 0] / self._steps[i]),
                     "q_spread": float(self._q_sums[i, 1] / self._steps[i]),
                     "value_bound": float("nan") if bound is None else bound}
                self._q_sums[i] = 0.0
            rec = EpisodeRecord(len(self.curve.records), float(info.get("oracle_return", np.nan)),
                                float(info.get("learnt_return", np.nan)), int(self._steps[i]),
                                time.perf_counter() - self._t0, dict(info.get("oracle_components", {})), q)
            self.curve.records.append(rec)
            self._steps[i] = 0
            if self.keeper is not None:
                self.keeper.on_episode(self.model, rec.learnt_return, rec.oracle_return, q.get("q_max"), bound)
            if self.on_episode is not None:
                self.on_episode(rec, info)
        if self.max_episodes is not None and len(self.curve.records) >= self.max_episodes:
            self._stop_next = True
        return True

    def _add_q_values(self) -> None:
        """A value-based agent (SB3's `q_net`): add max_a Q and max_a Q - min_a Q of the states the
        agent acted in (the observations before this step; ~30 µs per step)."""
        q_net = getattr(self.model, "q_net", None)
        obs = getattr(self.model, "_last_obs", None)
        if q_net is None or obs is None:
            return
        with torch.no_grad():
            q = q_net(torch.as_tensor(np.asarray(obs), dtype=torch.float32)).numpy()
        if self._q_sums is None:
            self._q_sums = np.zeros((len(q), 2))
        self._q_sums[:, 0] += q.max(1)
        self._q_sums[:, 1] += q.max(1) - q.min(1)


def value_bound_high(model) -> float | None:
    """The upper end of the value bound the agent's targets are clipped to (None: not bounded)."""
    bound = getattr(model, "value_bound", None)
    return None if bound is None else float(bound.high)


def make_keeper(cfg: dict) -> PolicyKeeper | None:
    """The config's policy keeper (`keep_every` episodes a snapshot; 0: keep the last policy)."""
    from .config import trust_settings

    every = trust_settings(cfg)["keep_every"]
    return PolicyKeeper(every) if every > 0 else None


def end_of_run(curve: LearningCurve, model, keeper: PolicyKeeper | None):
    """(the kept snapshot or None for the last policy, the collapse report) of a finished run."""
    kept = keeper.kept() if keeper is not None else None
    return kept, collapse_report(curve, value_bound_high(model), kept.episode if kept else None)


@dataclass
class AgentRun:
    """model: the agent with the kept policy's weights; collapse: the end-of-run report."""

    model: object
    curve: LearningCurve
    seconds: float
    out: Path | None
    collapse: CollapseReport | None = None
    kept_checkpoint: str | None = None  # the reward model the kept policy acted on (None: `checkpoint`)
    model_check: object | None = None  # model_check.AgentEpisodesCheck: the model where the agent went


def train_agent(task: str, reward: str, checkpoint: str | Path | None = None,
                episodes: int | None = None, seed: int = 0, out: str | Path | None = None,
                env_seed: int | None = None, n_envs: int = 1, progress: bool = True,
                config: str | Path | None = None, on_episode=None, served: str | None = None,
                oracle: str = "", callback: EpisodeCurveCallback | None = None, observe: str = "state",
                **overrides) -> AgentRun:
    """Train the paper's agent for `task` on reward `reward` ("model" with `checkpoint`, "oracle",
    "oracle-no-hidden") for `episodes` episodes (default: the config's).

    seed: SB3's seed (weights, exploration, replay sampling); env_seed: episode e of env i resets
    with `env_seed + i * 10**6 + e` (default env_seed = seed), as an env_sim node with
    `seed:=env_seed` does for env 0. served: what of the model's recurrent state the agent observes
    (reward "model": "h_tanh_c" = [h', tanh c'], "h_c" = [h', c'], "h" = h' only; None = the
    checkpoint's own; `nmrm_ros.mil.served_state`). oracle: a user's oracle function ("<module>:<function>") that
    judges every episode (and is the reward of "oracle" / "oracle-no-hidden"); default the task's.
    callback: an `EpisodeCurveCallback` (or a subclass, e.g. the reward-model loop's rounds) used
    in place of a plain one; its `max_episodes` is set to `episodes`. observe: the agent sees the
    task's state (an image state through a small CNN: `image_features`) or its privileged state
    (`wrappers.OBSERVE`; recorded in agent.json). overrides:
    settings of config/rl.yaml (e.g. learning_starts).
    """
    from stable_baselines3.common.vec_env import DummyVecEnv
    from stable_baselines3.common.monitor import Monitor

    from ..tasks import task_info
    from .config import algorithm_name, load_rl_config, make_algorithm
    from .wrappers import make_reward_env

    info = task_info(task)
    algo = algorithm_name(task)
    cfg = load_rl_config(algo, config, task=task, episodes=episodes, **overrides)
    torch.set_num_threads(int(cfg.get("threads", 1)))
    episodes = int(cfg["episodes"])
    env_seed = seed if env_seed is None else int(env_seed)
    seeds = [env_seed + i * 10**6 for i in range(n_envs)]
    envs = [make_reward_env(task, reward, checkpoint, seed=s, served=served, oracle=oracle, observe=observe)
            for s in seeds]
    if reward == "model":
        served = envs[0].served  # what the checkpoint serves where `served` was None
    vec = DummyVecEnv([lambda e=e: Monitor(e) for e in envs])
    model = make_algorithm(vec, algo, cfg, info.episode_length, seed=seed,
                           image_shape=info.image_shape if observe == "state" else ())
    # SB3 seeded env i with seed + i for its first reset; EpisodeSeeds takes the seed of a reset
    # as its base, so give each env its own base (VecEnv.seed can only add the env index).
    vec._seeds = seeds  # noqa: SLF001 - no public setter
    custom_callback = callback is not None  # a caller's (the loop's rounds) may swap the model
    if callback is None:
        callback = EpisodeCurveCallback(on_episode=on_episode)
    callback.max_episodes = episodes
    if callback.keeper is None:
        callback.keeper = make_keeper(cfg)
    t0 = time.perf_counter()
    with warnings.catch_warnings():  # SB3's progress bar is tqdm.rich, which warns that it is experimental
        warnings.simplefilter("ignore", TqdmExperimentalWarning)
        model.learn(total_timesteps=episodes * info.episode_length, callback=callback, progress_bar=progress)
    seconds = time.perf_counter() - t0
    keeper = callback.keeper
    kept, report = end_of_run(callback.curve, model, keeper)
    model_check = None
    # a model swapped during the run (the loop, which checks its last model itself): the keeper
    # was retagged; without a keeper, any caller's callback may have swapped
    swapped = keeper.tag is not None if keeper is not None else custom_callback
    if reward == "model" and not swapped:
        from .model_check import model_check_of_run

        records = callback.curve.records
        model_check = model_check_of_run(checkpoint, [r.learnt_return for r in records],
                                         [r.oracle_return for r in records])
    # a loop swaps models: the kept policy goes with the one it acted on (`PolicyKeeper.retag`)
    policy_checkpoint = (kept.tag if kept is not None else keeper.tag) if keeper is not None else None
    policy_checkpoint = policy_checkpoint or (str(checkpoint) if checkpoint is not None else None)
    out_dir = None
    if out is not None:
        out_dir = Path(out)
        save_agent(model, callback.curve, out_dir, {
            "task": task, "reward": reward, "algorithm": algo,
            "checkpoint": policy_checkpoint,
            "checkpoint_sha256": recorded_weights_sha256(policy_checkpoint) if reward == "model" else None,
            "served_state": served if reward == "model" else None, "oracle": oracle, "observe": observe, "seed": seed, "env_seed": env_seed, "n_envs": n_envs, "episodes": episodes,
            "seconds": seconds, "final_oracle_return": callback.curve.final_oracle_return(),
            "config": cfg, **({"model_check": model_check.to_dict()} if model_check else {})},
            keeper=keeper, collapse=report)
    if kept is not None:
        model.policy.load_state_dict(kept.weights)
    return AgentRun(model, callback.curve, seconds, out_dir, report, policy_checkpoint if reward == "model" else None,
                    model_check)


def save_agent(model, curve: LearningCurve, out: Path, meta: dict, keeper: PolicyKeeper | None = None,
               collapse: CollapseReport | None = None) -> None:
    """policy.zip (the kept policy: `keeper.kept()`, else the model as it is), last_policy.zip (the
    model as it is, when another policy is kept), curve.csv, curve.png and agent.json in `out`.
    The model keeps its own weights."""
    out.mkdir(parents=True, exist_ok=True)
    kept = keeper.kept() if keeper is not None else None
    if kept is None:
        model.save(out / "policy.zip")
        (out / "last_policy.zip").unlink(missing_ok=True)
    else:
        model.save(out / "last_policy.zip")
        live = {k: v.clone() for k, v in model.policy.state_dict().items()}
        model.policy.load_state_dict(kept.weights)
        try:
            model.save(out / "policy.zip")
        finally:
            model.policy.load_state_dict(live)
    if keeper is not None:
        meta = dict(meta, kept_policy=keeper.summary())
    if collapse is not None:
        meta = dict(meta, collapse=collapse.to_dict())
    curve.write_csv(out / "curve.csv")
    title = f"{meta.get('task')}: {meta.get('algorithm')} on reward {meta.get('reward')}, seed {meta.get('seed')}"
    if curve.records:
        curve.plot(out / "curve.png", title)
    (out / "agent.json").write_text(json.dumps(meta, indent=2, default=str))
