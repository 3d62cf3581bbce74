"""The three toy MIL datasets of the paper's App. C: Toggle Switch, Push Switch, Dial.

Each bag is an ordered sequence of 2-D instances with a bag size drawn uniformly from
min_size..max_size (inclusive; paper: 10..20), 5000 bags by default. Instance distributions:
- toggle_switch: ts ~ Bernoulli(0.5), v ~ U[0, 1]
- push_switch:   p  ~ Bernoulli(0.2), v ~ U[0, 1]
- dial:          m  ~ U[-1, 1],       v ~ U[-1, 1]
Labels come from `nmrm_ros.oracles.toy`.

The paper gives no distributions; its commented-out table has v in [0, 1] for the switches and
m, v in [-0.5, 0.5] for the dial. We chose the press probability and the dial range so that the
Markovian baseline's errors match what the paper reports for it (App. C.3, Instance Space NN):
- Push Switch: with presses at 0.5 the hidden switch is a coin flip at every step, uncorrelated
  in time, and the baseline's return MSE would be 15 x 1/12 = 1.25; the paper's 3.34 (reward MSE
  0.086 = 1/12) needs a switch that persists, which a press probability of about 0.2 gives.
- Dial: the baseline's reward MSE is E[d^2] E[v^2], 0.98 for m, v ~ U[-1, 1] at the mean step
  index of 10..20-instance bags; the paper reports 0.954 (U[-0.5, 0.5] would give 0.06).
"""

from __future__ import annotations

import numpy as np

from ..oracles import make_oracle
from .trajectories import TrajectoryDataset

TOY_DATASETS = ("toggle_switch", "push_switch", "dial")


def make_toy_dataset(name: str, n_bags: int = 5000, seed: int = 0, min_size: int = 10,
                     max_size: int = 20) -> TrajectoryDataset:
    """Draw and label `n_bags` toy bags; the same seed gives the same dataset."""
    if name not in TOY_DATASETS:
        raise ValueError(f"unknown toy dataset {name!r}; known: {', '.join(TOY_DATASETS)}")
    rng = np.random.default_rng(seed)
    lengths = rng.integers(min_size, max_size + 1, size=n_bags)
    shape = (n_bags, max_size)
    if name == "dial":
        first = rng.uniform(-1.0, 1.0, shape)
        second = rng.uniform(-1.0, 1.0, shape)
    else:
        p_on = 0.5 if name == "toggle_switch" else 0.2
        first = (rng.random(shape) < p_on).astype(np.float64)
        second = rng.uniform(0.0, 1.0, shape)
    mask = np.arange(max_size)[None, :] < lengths[:, None]
    states = (np.stack([first, second], axis=2) * mask[..., None]).astype(np.float32)
    labels = make_oracle(name).label(states, lengths=lengths)
    return TrajectoryDataset(name, states, lengths, labels.returns, labels.rewards, labels.hidden,
                             meta={"seed": seed, "generator": "toy", "min_size": min_size,
                                   "max_size": max_size})
