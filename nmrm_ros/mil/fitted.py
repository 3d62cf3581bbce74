"""Which members of an ensemble fitted their labels (keep_members "fitted", the default).

A member did not fit when its validation return MSE, as a fraction of the variance of its
validation returns (1 - R^2, "unexplained variance"), is over FITTED_FLOOR and over FITTED_RATIO
times the best member's: typically a member stuck on a plateau while the others learnt the task.
`pipeline.fit` leaves such members out of the served mean at the end of training, and asks the
plateau schedule to stop training them as soon as they are on a plateau (`training.train_ensemble`,
leave_out_unfitted), since they would be left out anyway unless they left the plateau later. Both
judge by the same numbers: training's validation criterion (feedback returns: the return MSE
against the validation labels, swapped ones included) over those labels' variance.

Chosen on 13 checkpoints of 6 tasks (the cue corridor, CartPole, the delivery robot, Charger,
Timer, MiniGrid; docs/guide/models.md): it leaves out the members stuck on a plateau (cue
corridor: 1 - R^2 = 1.0 beside 0.0004; Charger data seed 22: 0.065 beside 0.0034) and none of the
others (members apart by up to 20x, all under 1%).
"""

from __future__ import annotations

import numpy as np

FITTED_RATIO = 4.0
FITTED_FLOOR = 0.01
#: a served model whose validation 1 - R^2 is over this is reported as poorly fitted (`nmrm train`).
#: Measured on 15 runs of 5 tasks written after the settings were frozen (bench/time_to_accuracy.py,
#: tag h16p20, data seeds 20-22, the mean of the members served): CartPole, the cue corridor, the
#: delivery robot and MountainCar 0.0008-0.0069, the patrol robot 0.077 and 0.12 (held-out return
#: MSE 7.8 and 6.7) and 0.56 on data seed 22, whose members all stayed on the Markovian plateau
#: (27.8; the Markovian Instance Space NN's level there is ~26).
POORLY_FITTED = 0.25


def unfitted(unexplained: np.ndarray) -> np.ndarray:
    """(K,) bool: the members whose unexplained validation variance is over FITTED_FLOOR and over
    FITTED_RATIO times the least of the K (never the least itself); none when a value is NaN
    (labels that do not vary: nothing to judge by)."""
    u = np.asarray(unexplained, dtype=float)
    if np.isnan(u).any():
        return np.zeros(len(u), dtype=bool)
    return (u > FITTED_FLOOR) & (u > FITTED_RATIO * u.min())


def fitted_members(unexplained: list, serving: int) -> list:
    """The members kept, in order: all but the `unfitted` ones; `serving` is always kept."""
    out = unfitted(unexplained)
    return [m for m in range(len(out)) if m == serving or not out[m]]


def poorly_fitted(unexplained: float | None) -> bool:
    """A served model's validation 1 - R^2 is over POORLY_FITTED (False when not measured)."""
    return unexplained is not None and bool(np.isfinite(unexplained)) and unexplained > POORLY_FITTED


def label_variance(labels: np.ndarray) -> float:
    """The variance of the return labels (NaN, i.e. unlabelled, left out); 0 for fewer than two."""
    labels = np.asarray(labels, dtype=float)
    labels = labels[np.isfinite(labels)]
    return float(np.var(labels)) if len(labels) > 1 else 0.0
