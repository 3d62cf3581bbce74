"""Screened trajectory datasets (paper App. D.2): generate-and-select with per-class limits.

Each task has a trajectory classifier C_k and a limit p_k on the fraction of the dataset any class
may take. Trajectories are drawn (uniform-random policy for the navigation tasks, vectorised over
`batch` agents at once), classified, and examined in draw order: a trajectory is kept while its
class holds fewer than p_k * n_target trajectories (so at most ceil(p_k * n_target), and at least
1), otherwise discarded, until the dataset holds n_target. For Lunar Lander, a pool of trajectories from any policy is screened the same way
(`screen_pool`).

Class ids (int64) and their meaning:
- timer:   num_neg * 51 + num_pos (steps in the treasure with reward -1 / +1), 51 x 51 classes
- moving:  num_treasure (steps with reward 1), 0..100
- key:     0 no_key, 1 key_no_treasure, 2 treasure (visited after the key); with
           `key_fourth_class`, 3 treasure_no_key (treasure visited, never with the key), which
           is otherwise part of no_key
- charger: num_treasure * 20 + (charge_bin - 1), charge_bin = min(floor(mean charge / 0.05) + 1,
           20) over the steps in the treasure (bin 1 if never in it), 101 x 20 classes
- lunar_lander: pad_bin * 6 + take_off * 3 + hover_bin, pad_bin in {0, 1..49, 50+} -> 0, 1, 2;
           hover_bin in {0, 1..19, 20+} -> 0, 1, 2 (see `tasks.lunar_lander.lunar_lander_classes`)
"""

from __future__ import annotations

import time

import numpy as np

from ..oracles import make_oracle
from ..oracles.base import OracleLabels
from ..tasks import check_task, task_info
from ..tasks.info import ScreeningSpec
from ..tasks.navigation import EPISODE_LENGTH, rollout_random
from .trajectories import TrajectoryDataset, concatenate

KEY_CLASS_NAMES = ("no_key", "key_no_treasure", "treasure", "treasure_no_key")


def screening_spec(task: str, key_fourth_class: bool = False) -> ScreeningSpec:
    """The classes and limits of a task screened by class (its TaskInfo's rule)."""
    return _class_rule(task).screening_classes(key_fourth_class)


def classify(task: str, states: np.ndarray, labels: OracleLabels,
             key_fourth_class: bool = False) -> np.ndarray:
    """Class ids (n,) of labelled trajectories; states (n, L, d) are the labelled instances."""
    return _class_rule(task).classify(states, labels, key_fourth_class)


def _class_rule(task: str):
    info = task_info(task)
    if info.classify is None:
        raise ValueError(f"task {task!r} is screened by return bins, not by classes")
    return info


class Screener:
    """Keeps trajectories in the order offered while their class is under its limit."""

    def __init__(self, spec: ScreeningSpec, n_target: int) -> None:
        self.spec = spec
        self.n_target = int(n_target)
        self.counts: dict[int, int] = {}
        self.kept = 0
        self.examined = 0

    @property
    def full(self) -> bool:
        return self.kept >= self.n_target

    def offer(self, classes: np.ndarray) -> np.ndarray:
        """Examine classes in order until full; returns the indices kept."""
        keep = []
        for i, c in enumerate(classes.tolist()):
            if self.full:
                break
            self.examined += 1
            if self.counts.get(c, 0) < self.spec.max_count(c, self.n_target):
                self.counts[c] = self.counts.get(c, 0) + 1
                self.kept += 1
                keep.append(i)
        return np.asarray(keep, dtype=np.int64)


def screen_navigation(task: str, n_target: int = 5000, seed: int = 0, batch: int = 20000,
                      key_fourth_class: bool = False, max_draws: int = 50_000_000,
                      progress=None) -> TrajectoryDataset:
    """Screened dataset of a navigation task from uniform-random trajectories of length 100.

    Raises RuntimeError if `max_draws` trajectories were examined without filling the dataset.
    `progress(kept, examined)` is called after each batch if given.
    """
    if task_info(task).screening != "classes":
        raise ValueError(f"screen_navigation takes a task screened by classes of random rollouts (a navigation "
                         f"task), got {task!r}")
    rng = np.random.default_rng(seed)
    oracle = make_oracle(task)
    spec = screening_spec(task, key_fourth_class)
    capacity = sum(spec.max_count(c, n_target) for c in range(spec.n_classes))
    if capacity < n_target:
        raise ValueError(f"{task}: the class limits admit at most {capacity} trajectories, "
                         f"fewer than the {n_target} asked for")
    screener = Screener(spec, n_target)
    parts = []
    start = time.perf_counter()
    while not screener.full:
        if screener.examined >= max_draws:
            raise RuntimeError(f"{task}: only {screener.kept}/{n_target} trajectories kept after "
                               f"{screener.examined} draws (max_draws)")
        states, actions = rollout_random(batch, rng)
        instances = states[:, :EPISODE_LENGTH]
        labels = oracle.label(instances, actions)
        classes = classify(task, instances, labels, key_fourth_class)
        keep = screener.offer(classes)
        if keep.size:
            parts.append(TrajectoryDataset(task, instances[keep], labels.lengths[keep],
                                           labels.returns[keep], labels.rewards[keep],
                                           labels.hidden[keep], actions[keep], states[keep, -1],
                                           classes[keep]))
        if progress is not None:
            progress(screener.kept, screener.examined)
    seconds = time.perf_counter() - start
    return concatenate(parts, {"seed": seed, "generator": "random_policy_screening",
                                 "draws": screener.examined, "seconds": seconds,
                                 "key_fourth_class": key_fourth_class, "batch": batch})


def screen_pool(task: str, trajectories: list, n_target: int | None = None,
                meta: dict | None = None, screener: Screener | None = None) -> TrajectoryDataset:
    """Screen a pool of (states (L + 1, d), actions (L, m), terminated) trajectories, in order.

    `n_target` defaults to the pool size (the class limit is p * n_target). `screener`: one that
    has already examined earlier pools (to top a dataset up), else a new one."""
    check_task(task)
    n_target = len(trajectories) if n_target is None else n_target
    oracle = make_oracle(task)
    horizon = max(len(a) for _, a, _ in trajectories)
    n = len(trajectories)
    d = trajectories[0][0].shape[1]
    m = trajectories[0][1].shape[1]
    states = np.zeros((n, horizon, d), np.float32)
    actions = np.zeros((n, horizon, m), np.float32)
    final = np.zeros((n, d), np.float32)
    lengths = np.zeros(n, np.int64)
    for i, (s, a, _) in enumerate(trajectories):
        lengths[i] = len(a)
        states[i, : len(a)] = s[:-1]
        actions[i, : len(a)] = a
        final[i] = s[-1]
    labels = oracle.label(states, lengths=lengths)
    classes = classify(task, states, labels)
    screener = screener or Screener(screening_spec(task), n_target)
    keep = screener.offer(classes)
    meta = dict(meta or {}, generator="pool_screening", draws=screener.examined, pool=n)
    return TrajectoryDataset(task, states[keep], lengths[keep], labels.returns[keep],
                             labels.rewards[keep], labels.hidden[keep], actions[keep], final[keep],
                             classes[keep], meta)


def screen_lunar_lander(pool_size: int = 2000, seed: int = 0, n_target: int | None = None,
                        policy: str = "scripted", max_pools: int = 20, agent: str | None = None,
                        agent_fraction: float = 0.2, early: int = 15) -> TrajectoryDataset:
    """Roll out a pool of Lunar Lander episodes with `policy` and screen it (limit 0.2); while the
    classes' limits leave the dataset short of `n_target`, roll out and screen another pool
    (pool k: episode seeds seed + k * pool_size ...), at most `max_pools` in all (ValueError,
    one line, if still short). A first pool that fills the dataset gives what it always gave.

    `agent` (an agent trained on the oracle: `rl.agent_episodes.AgentEpisodes(policy.zip)`, or any
    object with its `rollout(task, n, seed, early)`): `agent_fraction` of each pool are its episodes
    instead (`early` as in `rollout_agent`; the paper's recycled oracle-agent episodes), shuffled into
    the pool in a seeded order."""
    from ..tasks.lunar_lander import SCRIPTED_PLANS, rollout_lunar_lander

    if agent is not None and not callable(getattr(agent, "rollout", None)):
        raise TypeError(f"agent must be an rl.agent_episodes.AgentEpisodes (or have its rollout), not {agent!r}")
    if agent is not None and not 0.0 < agent_fraction <= 1.0:
        raise ValueError(f"agent_fraction must be in (0, 1], got {agent_fraction}")
    start = time.perf_counter()
    n_target = pool_size if n_target is None else n_target
    screener = Screener(screening_spec("lunar_lander"), n_target)
    n_agent = round(pool_size * agent_fraction) if agent is not None else 0
    parts = []
    for k in range(max_pools):
        first = seed + k * pool_size
        pool = rollout_lunar_lander(pool_size - n_agent, seed=first, policy=policy) if n_agent < pool_size else []
        if n_agent:
            pool = pool + agent.rollout("lunar_lander", n_agent, seed=first + pool_size - n_agent, early=early)
            order = np.random.default_rng(first).permutation(len(pool))
            pool = [pool[i] for i in order]
        part = screen_pool("lunar_lander", pool, n_target, screener=screener)
        if len(part):
            parts.append(part)
        if screener.full:
            break
    else:
        raise ValueError(f"lunar_lander: only {screener.kept}/{n_target} episodes kept from "
                         f"{max_pools} pool(s) of {pool_size} (the classes' limits are full)")
    ds = concatenate(parts) if len(parts) > 1 else parts[0]
    ds.meta = {"seed": seed, "policy": policy, "generator": "pool_screening", "draws": screener.examined,
               "pool": pool_size, "pools": k + 1, "seconds": time.perf_counter() - start}
    if policy == "scripted":
        ds.meta["plans"] = SCRIPTED_PLANS
    if n_agent:
        ds.meta.update(agent=str(agent), agent_fraction=agent_fraction, early=early)
    return ds


def generate_screened(task: str, n_target: int = 5000, seed: int = 0, oracle: str = "",
                      **kwargs) -> TrajectoryDataset:
    """The screened dataset of any task: navigation, the paper's classes over random-policy
    trajectories; lunar_lander, its classes over a scripted pool of `pool_size` episodes (default
    2 * n_target; with kwargs policy, an oracle agent's `rl.agent_episodes.AgentEpisodes`, a fifth of
    them its episodes); a task of the user's (a task spec) or any task with a user's `oracle`
    ("<module>:<function>"), return bins over a pool of a random policy or of kwargs policy
    (`policy(state) -> action`, e.g. `rl.agent_episodes.load_screening_policy(policy.zip, ...)`;
    `return_screening`; kwargs pool_size, bins, policy); a pixel task, its state task's dataset
    rendered (`tasks.pixel_navigation.pixel_dataset`)."""
    info = task_info(task)
    if info.pixels_of:  # the state task's dataset, rendered
        from ..tasks.pixel_navigation import pixel_dataset

        return pixel_dataset(generate_screened(info.pixels_of, n_target, seed, oracle, **kwargs), task)
    if oracle or info.screening == "return_bins":
        from .return_screening import screen_by_return

        policy = kwargs.get("policy") or None
        if policy is not None and not callable(policy):
            raise TypeError(f"policy must be policy(state) -> action (rl.agent_episodes.load_screening_policy), "
                            f"not {policy!r}")
        return screen_by_return(task, make_oracle(task, oracle), n_target, seed=seed,
                                pool_size=kwargs.get("pool_size"), bins=kwargs.get("bins", 10),
                                progress=kwargs.get("progress"), policy=policy,
                                policy_name=str(policy or "random"))
    kwargs.pop("bins", None)
    policy = kwargs.pop("policy", None)
    if info.screening == "pool":
        pool_size = kwargs.pop("pool_size", None) or 2 * n_target
        kwargs.pop("progress", None)
        return screen_lunar_lander(pool_size=pool_size, seed=seed, n_target=n_target, agent=policy, **kwargs)
    if policy:
        raise ValueError("--policy screens by return bins: it needs your own task or --oracle "
                         "(or lunar_lander, whose pool it joins)")
    kwargs.pop("pool_size", None)
    return screen_navigation(task, n_target=n_target, seed=seed, **kwargs)
