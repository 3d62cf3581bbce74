"""Reward maps: the reward a model would give at every (x, y) of the arena, one step after a
fixed context (paper Fig. 6, top row; Lunar Lander: App. F).

A context is a probe trajectory cut at step t: the model consumes s_0..s_{t-1}, reaching its
hidden state h'_t; the map's value at grid point p is r'_t for s_t = p (the hidden state is then
updated with p itself, as it is online). The oracle's map is the same for the ground truth.
Maps are (n, n) arrays indexed [iy, ix] over `grid(n, task)`, y upwards. Navigation: the unit
square. Lunar Lander: x in [-1, 1], y in [0, 1.5], the lander at rest (velocities and angle 0),
both legs touching the ground on the bottom row (y = 0) and neither above it.
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
    # the "correct" probe first touches the pad at step 156 and has 50 steps there at step 205
    "lunar_lander": (Context("not landed yet", "correct", 100), Context("25 steps on the pad", "correct", 181),
                     Context("took off after 50 on the pad", "correct", 300)),
}


def extent(task: str | None = None) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) of a task's maps (its TaskInfo's arena; the unit square without one)."""
    from ..tasks import task_info

    return (task_info(task).arena if task else None) or (0.0, 1.0, 0.0, 1.0)


def grid(n: int = 41, task: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xs (n,), ys (n,), points (n * n, d) float32 in row-major [iy, ix] order): navigation (d = 2)
    over [0, 1]^2; Lunar Lander (d = 8) as the module says."""
    from ..tasks import task_info

    x0, x1, y0, y1 = extent(task)
    xs, ys = np.linspace(x0, x1, n), np.linspace(y0, y1, n)
    gx, gy = np.meshgrid(xs, ys)
    points = np.stack([gx.ravel(), gy.ravel()], axis=1)
    if task:
        points = task_info(task).states_at(points)
    return xs, ys, points.astype(np.float32)


def _with_prefix(prefix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P, t + 1, d): the prefix followed by each point."""
    p = len(points)
    head = np.broadcast_to(prefix[None], (p, *prefix.shape))
    return np.concatenate([head, points[:, None, :]], axis=1)


def learnt_reward_map(model, prefix: np.ndarray, n: int = 41, task: str | None = None,
                      inputs=None) -> np.ndarray:
    """The model's r'_t over `task`'s grid after consuming `prefix` (t, d): (n, n); inputs: what
    the model reads of the states (`model_traces`; None: the states)."""
    _, _, points = grid(n, task)
    rewards, _ = model_traces(model, _with_prefix(np.asarray(prefix, np.float32), points), inputs=inputs)
    return rewards[:, -1].reshape(n, n)


def oracle_reward_map(task: str, prefix: np.ndarray, n: int = 41) -> np.ndarray:
    """The oracle's r_t over the task's grid after `prefix` (t, d): (n, n)."""
    _, _, points = grid(n, task)
    rewards, _ = oracle_traces(task, _with_prefix(np.asarray(prefix, np.float64), points))
    return rewards[:, -1].reshape(n, n)


def context_prefixes(task: str) -> list:
    """[(Context, prefix states (t, 2))] of a task's contexts."""
    probes = {p.name: s for p, s in probe_states(task)}
    return [(c, probes[c.probe][:c.t]) for c in CONTEXTS.get(task, ())]
