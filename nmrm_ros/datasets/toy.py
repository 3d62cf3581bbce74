"""The three toy MIL datasets of the paper's App. C: Toggle Switch, Push Switch, Dial.

Each bag is an ordered sequence of 2-D instances with a bag size drawn uniformly from
min_size..max_size (inclusive; paper: 10..20), 5000 bags by default. Instance distributions:
- toggle_switch: ts ~ Bernoulli(0.5), v ~ U[0, 1]
- push_switch:   p  ~ Bernoulli(0.5), v ~ U[0, 1]
- dial:          m  ~ U[-0.5, 0.5],   v ~ U[-0.5, 0.5]
(the ranges are those of the paper's commented-out dataset table). Labels come from
`nmrm_ros.oracles.toy`.
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
        first = rng.uniform(-0.5, 0.5, shape)
        second = rng.uniform(-0.5, 0.5, shape)
    else:
        first = (rng.random(shape) < 0.5).astype(np.float64)
        second = rng.uniform(0.0, 1.0, shape)
    mask = np.arange(max_size)[None, :] < lengths[:, None]
    states = (np.stack([first, second], axis=2) * mask[..., None]).astype(np.float32)
    labels = make_oracle(name).label(states, lengths=lengths)
    return TrajectoryDataset(name, states, lengths, labels.returns, labels.rewards, labels.hidden,
                             meta={"seed": seed, "generator": "toy", "min_size": min_size,
                                   "max_size": max_size})
