"""Calibration: a few return labels give a model of comparisons the units of returns.

Comparisons fix a model's returns only up to an offset and a scale: any r' = a r + b per step
fits them as well as r. An agent learns from r' itself, and a scale far from the labels' units
can make its value estimates diverge (Key, seed 2: an agent on a model of 4000 comparisons earns
5.9 where the same model mapped to return units earns 81.4). `fit_calibration` fits, for each
member, its predicted returns to N return labels by least squares,

    R'_i = a R_i + b L_i          (episode i: label R_i, length L_i steps, prediction R'_i)

and `calibrate` folds the inverse map r <- (r' - b) / a into the last layer of the reward head,
so every path (training metrics, the online model, the wrapper, serving) uses the calibrated
rewards without knowing about it. A gain a > 0 is required, so episodes of one length keep their
order (the navigation tasks: preference accuracy and reward correlation do not change); between
episodes of different lengths the per-step offset b is what the labels decide. Return and reward
MSE become meaningful.

Architectures whose reward is an affine function of the head's last layer: `csc_lstm`,
`instance_nn`, `instance_lstm` with output activation "none".
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from .architectures import REGISTRY
from .data import TrajectoryDataset
from .ensemble import MILEnsemble, _key
from .evaluation import batched_outputs

#: architectures whose per-step reward is the reward head's last linear layer (times return_scale)
CALIBRATABLE = tuple(name for name, arch in REGISTRY.items() if arch.reward_is_head_output)


class CalibrationError(ValueError):
    """The model cannot be calibrated, or the labels cannot calibrate it."""


@dataclass
class Calibration:
    """Per member: predicted = gain * label + bias per step (gain, bias: (K,), label units)."""

    gain: np.ndarray
    bias: np.ndarray
    labels: int

    def to_dict(self) -> dict:
        return {"gain": self.gain.tolist(), "bias_per_step": self.bias.tolist(), "labels": self.labels,
                "rewards": "(r' - bias_per_step) / gain"}


def check_calibratable(model: MILEnsemble) -> None:
    """Raise CalibrationError unless `model`'s rewards are affine in its head's last layer."""
    cfg = model.config
    if cfg.architecture not in CALIBRATABLE:
        raise CalibrationError(f"a {cfg.architecture} model cannot be calibrated (its rewards are differences of "
                               f"predicted returns); calibratable: {', '.join(CALIBRATABLE)}")
    if cfg.output_activation != "none":
        raise CalibrationError(f"a model with output activation {cfg.output_activation!r} cannot be calibrated "
                               f"(only 'none' keeps the rewards affine in the last layer)")


def fit_calibration(model: MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> Calibration:
    """Least-squares (gain, bias) per member from the episodes of `ds` that have a return label
    (NaN returns are unlabelled). Needs 2+ labelled episodes whose returns differ."""
    check_calibratable(model)
    labelled = np.flatnonzero(np.isfinite(ds.returns))
    if len(labelled) < 2 or np.ptp(ds.returns[labelled]) == 0:
        raise CalibrationError(f"calibration needs at least 2 return-labelled episodes with different returns; "
                               f"the data has {len(labelled)}"
                               + (" (all with the same return)" if len(labelled) >= 2 else ""))
    sub = ds.subset(labelled)
    predicted = np.concatenate([out.returns.double().numpy()
                                for out, _ in batched_outputs(model, sub, batch_size)], axis=1)  # (K, N)
    design = np.stack([sub.returns.astype(np.float64), sub.lengths.astype(np.float64)], axis=1)  # (N, 2)
    coef, *_ = np.linalg.lstsq(design, predicted.T, rcond=None)  # (2, K)
    gain, bias = coef[0], coef[1]
    if np.any(~np.isfinite(gain)) or np.any(gain <= 0):
        raise CalibrationError(f"the model orders the labelled episodes against their returns (fitted gain "
                               f"{', '.join(f'{g:.3g}' for g in gain)}): it cannot be calibrated on these labels")
    return Calibration(gain=gain, bias=bias, labels=len(sub))


def step_units(model: MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> Calibration:
    """The map that puts a model of comparisons in units of its largest step: the largest |r'_t|
    of its served mean (the members' mean reward) over the real steps of `ds`, as one gain for
    every member, no bias, so that `calibrate` gives rewards r'_t / gain (the mean at most 1 in
    size on those steps; the mean's order, correlation and every scale-free metric unchanged).
    Comparisons leave the scale free, and it is whatever training reached (~3 per oracle unit on
    Key from 4000 perfect comparisons); an agent's values and learning then depend on it (Key, 4000
    comparisons, data seed 2: greedy oracle return 52.7 unscaled, 77.0 in these units; 1000
    comparisons, seed 1: 61.1 and 80.1). CalibrationError for an architecture that cannot be scaled."""
    check_calibratable(model)
    # rewards are 0 beyond each bag's length (batched_outputs): the largest is over real steps
    largest = max(float(out.rewards.mean(0).abs().max()) for out, _ in batched_outputs(model, ds, batch_size))
    if not largest > 0:
        raise CalibrationError("the model pays 0 on every step of the episodes: it has no scale to take")
    return Calibration(gain=np.full(model.members, largest), bias=np.zeros(model.members), labels=0)


def calibrate(model: MILEnsemble, calibration: Calibration) -> MILEnsemble:
    """A copy of `model` whose per-step rewards are (r' - bias) / gain (member by member)."""
    check_calibratable(model)
    if len(calibration.gain) != model.members:
        raise CalibrationError(f"the calibration has {len(calibration.gain)} members, the model {model.members}")
    if not model._head:
        raise CalibrationError("the model has no reward head to calibrate")
    out = copy.deepcopy(model)
    last = out._head[-1]
    weight = out.params[_key(f"head.{last}.weight")]  # (K, 1, in)
    bias = out.params[_key(f"head.{last}.bias")]  # (K, 1)
    scale = float(out.return_scale)
    gain = torch.as_tensor(calibration.gain, dtype=weight.dtype)
    shift = torch.as_tensor(calibration.bias, dtype=weight.dtype)
    with torch.no_grad():
        # reward = (W z + c) * s  ->  ((W z + c) * s - shift) / gain
        weight.div_(gain[:, None, None])
        bias.copy_((bias - shift[:, None] / scale) / gain[:, None])
    return out
