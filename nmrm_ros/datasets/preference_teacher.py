"""Simulated teachers: pairwise comparisons of trajectories from their oracle rewards, with the
knobs of B-Pref (Lee et al. 2021) for the ways people are not oracles.

A teacher compares trajectories a and b by their (myopically discounted) returns
R = sum_t gamma^(len - 1 - t) r_t (gamma = 1: the return itself):
- skip: no answer when both R_a and R_b are below `skip` (neither shows anything worth judging);
- equal: p = 0.5 when |R_a - R_b| <= `equal`;
- rationality beta: a is preferred with probability sigmoid(beta (R_a - R_b)) (Bradley-Terry
  sampling); beta = inf always prefers the better one;
- mistake: the answer is flipped with probability `mistake`.
Every draw comes from one seeded generator: the same teacher, dataset, pairs and seed give the
same answers.
"""

from __future__ import annotations

import dataclasses

import math
from dataclasses import asdict, dataclass

import numpy as np

from .trajectories import TrajectoryDataset


#: The named teachers the benchmarks compare (their knobs; `SimulatedTeacher(**TEACHERS[name])`):
#: perfect (always the better return) and noisy (beta 1, one answer in ten flipped).
TEACHERS = {"perfect": {}, "noisy": {"beta": 1.0, "mistake": 0.1}}


@dataclass(frozen=True)
class SimulatedTeacher:
    """B-Pref's teacher knobs (defaults: a perfect teacher)."""

    beta: float = math.inf  # rationality (1 / return units); inf: always the better one
    mistake: float = 0.0  # probability of flipping an answer
    equal: float = 0.0  # |R_a - R_b| <= equal: "equal" (p = 0.5)
    gamma: float = 1.0  # myopia: the weight of step t is gamma^(len - 1 - t)
    skip: float = -math.inf  # both discounted returns below this: no answer

    def check(self) -> "SimulatedTeacher":
        """self, or a ValueError naming the first knob out of its range."""
        rules = [("beta", self.beta > 0, "> 0 (inf: a perfect teacher)"),
                 ("mistake", 0 <= self.mistake <= 1, "in [0, 1]"),
                 ("equal", self.equal >= 0, ">= 0"), ("gamma", 0 < self.gamma <= 1, "in (0, 1]"),
                 ("skip", not math.isnan(self.skip), "a number (-inf: never skip)")]
        for name, ok, allowed in rules:
            if not ok or math.isnan(getattr(self, name)):
                raise ValueError(f"teacher setting {name} must be {allowed}, got {getattr(self, name)!r}")
        return self

    def to_dict(self) -> dict:
        return {k: (str(v) if math.isinf(v) else v) for k, v in asdict(self).items()}

    def judge(self, rewards: np.ndarray) -> float:
        """One trajectory's return as this teacher weighs it: rewards (L,) -> sum_t gamma^(L-1-t) r_t."""
        rewards = np.asarray(rewards, dtype=np.float64)
        return float((rewards * self.gamma ** np.arange(len(rewards))[::-1]).sum())

    def decide(self, ra: np.ndarray, rb: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(p (m,), answered (m,) bool) for judged returns ra, rb (m,): p = 1 a better, 0 b
        better, 0.5 equal; not answered: both below `skip`."""
        ra, rb = np.atleast_1d(np.asarray(ra, np.float64)), np.atleast_1d(np.asarray(rb, np.float64))
        diff = ra - rb
        if math.isinf(self.beta):
            p = (diff > 0).astype(np.float64)
        else:
            chance = 1.0 / (1.0 + np.exp(-np.clip(self.beta * diff, -500, 500)))
            p = (rng.random(len(diff)) < chance).astype(np.float64)
        flip = rng.random(len(diff)) < self.mistake
        p = np.where(flip, 1.0 - p, p)
        p = np.where(np.abs(diff) <= self.equal, 0.5, p)
        return p, ~((ra < self.skip) & (rb < self.skip))

    def judged_returns(self, ds: TrajectoryDataset) -> np.ndarray:
        """(n,) each trajectory's return as this teacher weighs it (oracle rewards, myopia gamma)."""
        steps = np.arange(ds.rewards.shape[1])[None, :]
        age = ds.lengths[:, None] - 1 - steps  # 0 at the last step
        weights = np.where(age >= 0, self.gamma ** np.maximum(age, 0), 0.0)
        return (ds.rewards * weights).sum(axis=1)

    def answer(self, ds: TrajectoryDataset, pairs: np.ndarray, seed: int) -> np.ndarray:
        """(m', 3) rows (a, b, p) for the pairs (m, 2) the teacher answers (skipped ones left out)."""
        self.check()
        rng = np.random.default_rng([int(seed), 0xBEEF])
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        r = self.judged_returns(ds)
        p, answered = self.decide(r[pairs[:, 0]], r[pairs[:, 1]], rng)
        return np.column_stack([pairs[answered], p[answered]]).astype(np.float64)


def draw_pairs(n: int, pairs: int, seed: int) -> np.ndarray:
    """(pairs, 2) distinct pairs (a != b) of range(n), uniformly drawn without repeats where
    n (n - 1) / 2 allows (else with repeats), in random order; seeded."""
    if n < 2:
        raise ValueError(f"pairs need at least 2 trajectories, got {n}")
    if pairs < 1:
        raise ValueError(f"the number of pairs must be >= 1, got {pairs}")
    rng = np.random.default_rng([int(seed), 0xAB])
    total = n * (n - 1) // 2
    if pairs <= total // 2:  # rejection: few repeats to reject
        seen: set = set()
        out = []
        while len(out) < pairs:
            a, b = rng.integers(0, n, size=2)
            key = (min(a, b), max(a, b))
            if a != b and key not in seen:
                seen.add(key)
                out.append((a, b))
        return np.asarray(out, dtype=np.int64)
    a, b = np.triu_indices(n, k=1)
    pick = rng.permutation(total)[:pairs] if pairs <= total else rng.integers(0, total, size=pairs)
    swap = rng.random(len(pick)) < 0.5  # which one is shown first is random too
    first, second = a[pick], b[pick]
    return np.column_stack([np.where(swap, second, first), np.where(swap, first, second)]).astype(np.int64)


def with_preferences(ds: TrajectoryDataset, pairs: int, teacher: SimulatedTeacher, seed: int) -> TrajectoryDataset:
    """`ds` with `pairs` comparisons (drawn and answered with `seed`) as its preferences, and the
    teacher and the pair count in meta["preferences"]. The return labels stay (the true returns),
    so that the same episodes can be trained from either kind of feedback."""
    prefs = teacher.answer(ds, draw_pairs(len(ds), pairs, seed), seed)
    meta = dict(ds.meta, preferences={"teacher": teacher.to_dict(), "pairs_asked": int(pairs),
                                      "answered": int(len(prefs)), "seed": int(seed)})
    return dataclasses.replace(ds, meta=meta, preferences=prefs)
