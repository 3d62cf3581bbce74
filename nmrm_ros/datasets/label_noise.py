"""Label noise by swapping (paper Sec. 5.2, after Rolnick et al. 2017): a fraction p of the labels
are exchanged at random between trajectories, so the multiset of labels (the marginal label
distribution) is unchanged and no out-of-distribution return appears.

    source = swap_sources(n, p, rng)    # trajectory i now carries the label of trajectory source[i]
    noisy = returns[source]

Exactly round(p * n) trajectories get another trajectory's label: the chosen ones pass their labels
round a random cycle (a derangement), the others keep their own. (Two trajectories may share a
label value, so fewer *values* may change.)
"""

from __future__ import annotations

import numpy as np


def swap_sources(n: int, p: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) int64: the index whose label each of n trajectories carries after swapping a fraction
    p in [0, 1]."""
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"label swap fraction must be in [0, 1], got {p}")
    source = np.arange(n, dtype=np.int64)
    m = int(round(p * n))
    if m < 2:
        if m == 1:
            raise ValueError(f"swapping {p} of {n} labels is one label: nothing to swap it with")
        return source
    chosen = rng.choice(n, size=m, replace=False)
    source[chosen] = np.roll(chosen, 1)
    return source


def swap_labels(returns: np.ndarray, p: float, rng: np.random.Generator) -> np.ndarray:
    """A copy of `returns` (n,) with a fraction p swapped between trajectories."""
    returns = np.asarray(returns)
    return returns[swap_sources(len(returns), p, rng)]


class OnlineLabelSwapper:
    """Label swapping for a labeller that must label each episode as it ends (labeller_oracle).

    The first `pool` episodes get their true returns, and copies of them fill a pool. After that,
    each episode's label is, with probability p, exchanged with a random pool entry: the entry is
    published and this episode's true return takes its place in the pool (to be published for a
    later swapped episode); otherwise its true return is published. So every published value is a
    true return of an episode of this run, and the published labels are the true returns, each
    once, except for at most 2 * pool of them (the pool's first copies, and what it holds at the
    end): as offline, the label distribution is unchanged.
    """

    def __init__(self, p: float, pool: int, rng: np.random.Generator) -> None:
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"label swap fraction must be in [0, 1], got {p}")
        if pool < 1:
            raise ValueError(f"the swap pool needs at least one episode, got {pool}")
        self.p, self.size, self.rng = float(p), int(pool), rng
        self.pool: list = []
        self.swapped = 0

    def label(self, true_return: float) -> float:
        """The label to publish for an episode whose true return is `true_return`."""
        value = float(true_return)
        if len(self.pool) < self.size:
            self.pool.append(value)
            return value
        if self.rng.random() < self.p:
            j = int(self.rng.integers(self.size))
            value, self.pool[j] = self.pool[j], value
            self.swapped += 1
        return value
