"""Screened datasets of any task with any oracle: balance the return histogram.

The paper screens its tasks by task-specific trajectory classes (App. D.2), because a random
policy rarely shows the interesting behaviour. For a task of a user's, we know nothing but the
oracle's return, so the classes are return bins, and the rule is the same in spirit:

1. roll out a pool of `pool_size` episodes (uniform-random actions, or a Stable-Baselines3
   policy of plain states, acting as it explores: `rl.agent_episodes.load_screening_policy`), episode e reset with
   seed `seed + e`;
2. label every episode with the oracle; cut the pool's return range [min, max] into `bins`
   equal-width bins (class id = bin index, 0 = lowest returns);
3. keep, in draw order, at most `cap` episodes per bin, `cap` the smallest number for which the
   pool fills the `n` asked for: the most even return histogram the pool allows (rare returns
   are all kept, common ones thinned out).

An oracle whose returns are all equal gives one bin (nothing to balance); a pool of fewer than `n`
episodes is refused.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import numpy as np

from ..oracles import Oracle, OracleError
from ..tasks import make_env, task_info
from ..tasks.gym_task import TaskSpecError, encoder_weights_sha256
from .trajectories import TrajectoryDataset

Policy = Callable[[np.ndarray], np.ndarray]


def rollout_episodes(task: str, episodes: int, seed: int = 0, policy: Policy | None = None,
                     progress: Callable[[int], None] | None = None) -> list:
    """`episodes` episodes of `task`: a list of (states (L + 1, d) float32, actions (L, A) float32),
    and privileged states (L + 1, p) float32 third where the task has them (`info["privileged"]`).

    Episode e is reset with seed `seed + e`; `policy(state) -> action` (None: uniform random,
    the action space seeded with `seed`). A Discrete action is stored as one column."""
    env = make_env(task)
    env.action_space.seed(seed)
    out = []
    try:
        for e in range(episodes):
            try:
                out.append(_episode(env, seed + e, policy))
            except (TaskSpecError, OracleError):
                raise
            except Exception as exc:  # noqa: BLE001 - the user's env or policy: one line naming it
                raise TaskSpecError(f"task {task}: episode {e} (seed {seed + e}) failed: "
                                    f"{type(exc).__name__}: {exc}") from None
            if progress is not None:
                progress(e + 1)
    finally:
        env.close()
    return out


def _episode(env, seed: int, policy: Policy | None) -> tuple:
    obs, info = env.reset(seed=seed)
    states, actions, privileged = [np.asarray(obs, np.float32)], [], [info.get("privileged")]
    done = False
    while not done:
        action = env.action_space.sample() if policy is None else policy(obs)
        obs, _, terminated, truncated, info = env.step(action)
        states.append(np.asarray(obs, np.float32))
        actions.append(np.asarray(action, np.float32).reshape(-1))
        privileged.append(info.get("privileged"))
        done = terminated or truncated
    if not actions:
        raise TaskSpecError("the episode ended at reset")
    if privileged[0] is None:
        return np.stack(states), np.stack(actions)
    return np.stack(states), np.stack(actions), np.stack(privileged).astype(np.float32)


def return_bins(returns: np.ndarray, bins: int) -> np.ndarray:
    """Bin index (n,) int64 of each return: `bins` equal-width bins over [min, max] (0 if all equal)."""
    returns = np.asarray(returns, dtype=np.float64)
    low, high = float(returns.min()), float(returns.max())
    if high <= low:
        return np.zeros(len(returns), np.int64)
    idx = np.floor((returns - low) / (high - low) * bins).astype(np.int64)
    return np.minimum(idx, bins - 1)


def balanced_keep(classes: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """(indices kept in draw order, cap): at most `cap` per class, `cap` the smallest that keeps `n`."""
    counts = np.bincount(classes)
    cap = 1
    while np.minimum(counts, cap).sum() < n:
        cap += 1
    taken = np.zeros_like(counts)
    keep = []
    for i, c in enumerate(classes):
        if taken[c] < cap and len(keep) < n:
            taken[c] += 1
            keep.append(i)
    return np.asarray(keep, np.int64), cap


def screen_by_return(task: str, oracle: Oracle, n: int, pool_size: int | None = None, seed: int = 0,
                     bins: int = 10, policy: Policy | None = None, policy_name: str = "random",
                     progress: Callable[[int], None] | None = None) -> TrajectoryDataset:
    """A screened dataset of `n` episodes of `task` labelled by `oracle` (module docstring).

    pool_size defaults to 4 n. Episodes may vary in length (states are zero-padded to the
    longest; `lengths` says how many steps each has)."""
    pool_size = 4 * n if pool_size is None else pool_size
    if pool_size < n:
        raise ValueError(f"a pool of {pool_size} episodes cannot fill {n}")
    if bins < 1:
        raise ValueError(f"bins must be at least 1, got {bins}")
    start = time.perf_counter()
    everything = label_rollouts(task, oracle, rollout_episodes(task, pool_size, seed, policy, progress))
    classes = return_bins(everything.returns, bins)
    keep, cap = balanced_keep(classes, n)
    ds = everything.subset(keep)
    horizon = int(ds.lengths.max())
    meta = {**everything.meta, "seed": seed, "generator": "return_screening", "policy": policy_name, "pool": pool_size,
            "bins": bins, "cap_per_bin": cap, "oracle": getattr(oracle, "spec", task),
            "seconds": time.perf_counter() - start}
    return replace(ds, states=ds.states[:, :horizon], rewards=ds.rewards[:, :horizon],
                   hidden=ds.hidden[:, :horizon], actions=ds.actions[:, :horizon], classes=classes[keep],
                   privileged=None if ds.privileged is None else ds.privileged[:, :horizon],
                   meta=meta)


def label_rollouts(task: str, oracle: Oracle, pool: list, meta: dict | None = None) -> TrajectoryDataset:
    """Every episode of `pool` (a list of (states (L + 1, d), actions (L, A)[, privileged (L + 1,
    p)]), as `rollout_episodes` gives) labelled by `oracle` (on the privileged states where there
    are some), in order: states zero-padded to the longest episode, the last observation of each
    in `final_states`; states that are all pixels are kept as uint8. A frozen encoder's states
    record its weights file's SHA-256 (meta `encoder_sha256`: training and the dataset cache refuse
    them once the file holds other weights)."""
    info = task_info(task)
    meta = dict(meta or {})
    encoder = encoder_weights_sha256(task)
    if encoder:
        meta["encoder_sha256"] = encoder[1]
    horizon = max(len(item[1]) for item in pool)
    width = pool[0][1].shape[1]
    dtype = np.uint8 if info.image_values and info.image_values == info.state_size else np.float32
    states = np.zeros((len(pool), horizon, info.state_size), dtype)
    actions = np.zeros((len(pool), horizon, width), np.float32)
    final = np.zeros((len(pool), info.state_size), dtype)
    lengths = np.zeros(len(pool), np.int64)
    with_privileged = all(len(item) == 3 for item in pool)
    privileged = np.zeros((len(pool), horizon, pool[0][2].shape[1]), np.float32) if with_privileged else None
    for i, (s, a, *p) in enumerate(pool):
        lengths[i] = len(a)
        states[i, : len(a)], actions[i, : len(a)], final[i] = s[:-1], a, s[-1]
        if with_privileged:
            privileged[i, : len(a)] = p[0][:-1]
    labels = oracle.label(states if privileged is None else privileged, actions, lengths)
    return TrajectoryDataset(task, states, lengths, labels.returns, labels.rewards, labels.hidden,
                             actions, final, None, meta, privileged=privileged)
