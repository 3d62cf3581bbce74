"""Reward maps: the reward a model would give at every (x, y) of the arena, one step after a
fixed context (paper Fig. 6, top row).

A context is a probe trajectory cut at step t: the model consumes s_0..s_{t-1}, reaching its
hidden state h'_t; the map's value at grid point p is r'_t for s_t = p (the hidden state is then
updated with p itself, as it is online). The oracle's map is the same for the ground truth.
Maps are (n, n) arrays indexed [iy, ix] over `grid(n)`, y upwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .probes import probe_states
from .traces import model_traces, oracle_traces


@dataclass(frozen=True)
class Context:
    """label: what the hidden state means at this point; probe: a probe name of the task; t:
    how many of its states come before the mapped step."""

    label: str
    probe: str
    t: int


CONTEXTS: dict = {
    "timer": (Context("t = 20: the treasure costs", "optimal", 20),
              Context("t = 70: the treasure pays", "optimal", 70)),
    "moving": tuple(Context(f"t = {t}", "optimal left", t) for t in (15, 40, 60, 85)),
    "key": (Context("no key", "no key", 3), Context("key held", "key first", 10)),
    "charger": (Context("charge 0.2", "over-charged", 14), Context("charge 0.5", "over-charged", 29),
                Context("charge 0.9", "over-charged", 49)),
}


def grid(n: int = 41) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xs (n,), ys (n,), points (n * n, 2) float32 in row-major [iy, ix] order) over [0, 1]^2."""
    xs = np.linspace(0.0, 1.0, n)
    gx, gy = np.meshgrid(xs, xs)
    return xs, xs, np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)


def _with_prefix(prefix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P, t + 1, d): the prefix followed by each point."""
    p = len(points)
    head = np.broadcast_to(prefix[None], (p, *prefix.shape))
    return np.concatenate([head, points[:, None, :]], axis=1)


def learnt_reward_map(model, prefix: np.ndarray, n: int = 41) -> np.ndarray:
    """The model's r'_t over the grid after consuming `prefix` (t, d): (n, n)."""
    _, _, points = grid(n)
    rewards, _ = model_traces(model, _with_prefix(np.asarray(prefix, np.float32), points))
    return rewards[:, -1].reshape(n, n)


def oracle_reward_map(task: str, prefix: np.ndarray, n: int = 41) -> np.ndarray:
    """The oracle's r_t over the grid after `prefix` (t, d): (n, n)."""
    _, _, points = grid(n)
    rewards, _ = oracle_traces(task, _with_prefix(np.asarray(prefix, np.float64), points))
    return rewards[:, -1].reshape(n, n)


def context_prefixes(task: str) -> list:
    """[(Context, prefix states (t, 2))] of a task's contexts."""
    probes = {p.name: s for p, s in probe_states(task)}
    return [(c, probes[c.probe][:c.t]) for c in CONTEXTS.get(task, ())]
