"""Test metrics as the paper's tables define them.

return MSE: mean over test bags of (predicted return - true return)^2.
reward MSE: mean over all real steps of all test bags of (predicted r'_t - oracle r_t)^2.
Both in label units; `*_scaled` divide errors by the model's return_scale (Lunar Lander: 100).
reward MSE, time profile: the part of the reward MSE that is the mean error at each step index t
over the bags (sum over t of n_t * mean_error_t^2 / steps; the rest is the spread of the errors
around that mean). A model that fits the returns but adds a zero-sum function of time to every
bag's rewards (invisible in the returns when all bags are equal in length) shows its error here.

Metrics that do not depend on the returns' offset and scale (what preferences fix):
preference accuracy: over all pairs of bags whose return labels differ, the fraction the model
orders as the labels do (a tie in prediction counts one half); comparison accuracy: the same over
the dataset's labelled comparisons that are not "equal"; reward correlation: Pearson's r between
the predicted r'_t and the oracle's r_t over all real steps; reward correlation, centred: the
same after subtracting from both each step index's mean over the bags. When every bag has the
same length, adding any function of time g(t) to every bag's rewards changes no return
difference, so comparisons cannot fix it (returns fix it up to sum_t g(t) = 0); the centred
correlation ignores it. Bags without a return label (NaN) are left out of the return MSE and the
preference accuracy.
"""

from __future__ import annotations

import numpy as np
import torch

from ..datasets.trajectories import TrajectoryDataset
from .data import BagTensors
from .ensemble import MILEnsemble, as_ensemble
from .models import MILRewardModel


def batched_outputs(model: MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512):
    """(output, lengths) of `model` on the bags of `ds` in order, batch by batch, in eval mode and
    without gradients (the model's mode restored afterwards): MILOutput returns (K, B), rewards
    (K, B, T) zero beyond each of the lengths (B,)."""
    bags = BagTensors(ds, model.patch_layout)
    was_training = model.training
    model.eval()
    try:
        rows = bags.eval_rows(batch_size, model.members)
        for start in range(0, len(bags), rows):
            x, lengths, _ = bags.batch(torch.arange(start, min(start + rows, len(bags))))
            with torch.no_grad():  # not around the yield: grad mode would leak into the caller
                out = model(x, lengths, patch_ordered=bags.patch_ordered)
            yield out, lengths
    finally:
        model.train(was_training)


@torch.no_grad()
def evaluate(model: MILRewardModel | MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> dict:
    """{"return_mse", "reward_mse", "bags", ...} of a model or an ensemble, scored on its mean
    prediction (returns and rewards averaged over the members); with K > 1 members "return_std"
    adds the mean over bags of the members' return std."""
    model = as_ensemble(model).eval()
    bags = BagTensors(ds, model.patch_layout)
    batch_size = bags.eval_rows(batch_size, model.members)
    ret_se, rew_se, steps, spread = 0.0, 0.0, 0, 0.0
    predicted, step_pred, step_true, step_index = [], [], [], []
    err_by_t = torch.zeros(bags.x.shape[1], dtype=torch.float64)  # summed errors per step index
    n_by_t = torch.zeros(bags.x.shape[1], dtype=torch.float64)
    for start in range(0, len(bags), batch_size):
        index = torch.arange(start, min(start + batch_size, len(bags)))
        x, lengths, returns = bags.batch(index)
        out = model(x, lengths, patch_ordered=bags.patch_ordered)
        spread += float(out.returns.std(0, unbiased=False).sum())
        pred_returns, pred_rewards = out.returns.mean(0), out.rewards.mean(0)
        predicted.append(pred_returns.double().numpy())
        ret_se += float(torch.nan_to_num((pred_returns - returns) ** 2).sum())
        mask = torch.arange(x.shape[1])[None, :] < lengths[:, None]
        step_pred.append(pred_rewards[mask].double().numpy())
        step_true.append(bags.rewards[index, : x.shape[1]][mask].double().numpy())
        step_index.append(torch.arange(x.shape[1]).expand_as(mask)[mask].numpy())
        true_rewards = bags.rewards[index, : x.shape[1]]
        err = (pred_rewards - true_rewards) * mask
        rew_se += float((err ** 2).sum())
        steps += int(mask.sum())
        err_by_t[: x.shape[1]] += err.double().sum(0)
        n_by_t[: x.shape[1]] += mask.double().sum(0)
    labelled = np.isfinite(ds.returns)
    n = int(labelled.sum())
    profile = float((err_by_t ** 2 / n_by_t.clamp(min=1)).sum()) / max(steps, 1)
    predicted = np.concatenate(predicted) if predicted else np.zeros(0)
    metrics = {"return_mse": ret_se / n if n else float("nan"), "reward_mse": rew_se / max(steps, 1),
               "reward_mse_time_profile": profile, "bags": len(bags)}
    metrics["preference_accuracy"], metrics["preference_pairs"] = preference_accuracy(
        predicted[labelled], ds.returns[labelled])
    if ds.preferences is not None and len(ds.preferences):
        metrics["comparison_accuracy"], metrics["comparisons"] = comparison_accuracy(predicted, ds.preferences)
    flat = [np.concatenate(x) if x else np.zeros(0) for x in (step_pred, step_true, step_index)]
    metrics["reward_correlation"] = correlation(flat[0], flat[1])
    metrics["reward_correlation_centred"] = correlation(*(centred(v, flat[2]) for v in flat[:2]))
    if model.members > 1:
        metrics["return_std"] = spread / max(len(bags), 1)
    scale = float(model.return_scale)
    if scale != 1.0:
        metrics["return_mse_scaled"] = metrics["return_mse"] / scale ** 2
        metrics["reward_mse_scaled"] = metrics["reward_mse"] / scale ** 2
        metrics["reward_mse_time_profile_scaled"] = profile / scale ** 2
    return metrics


def preference_accuracy(predicted: np.ndarray, labels: np.ndarray, chunk: int = 512) -> tuple[float, int]:
    """(fraction of the pairs i < j with labels[i] != labels[j] that `predicted` orders the same
    way, a tie counting one half; the number of such pairs). NaN accuracy without any pair.
    predicted, labels: (n,)."""
    predicted, labels = np.asarray(predicted, np.float64), np.asarray(labels, np.float64)
    right, pairs = 0.0, 0
    for start in range(0, len(labels), chunk):
        rows = slice(start, start + chunk)
        upper = np.arange(start, min(start + chunk, len(labels)))[:, None] < np.arange(len(labels))[None, :]
        true = np.sign(labels[rows, None] - labels[None, :])
        guess = np.sign(predicted[rows, None] - predicted[None, :])
        counted = upper & (true != 0)
        pairs += int(counted.sum())
        right += float(np.where(guess == true, 1.0, np.where(guess == 0, 0.5, 0.0))[counted].sum())
    return (right / pairs if pairs else float("nan")), pairs


def comparison_accuracy(predicted: np.ndarray, preferences: np.ndarray) -> tuple[float, int]:
    """(fraction of the labelled comparisons (a, b, p) with p != 0.5 whose better one has the
    higher predicted return, a tie counting one half; their number)."""
    decided = preferences[preferences[:, 2] != 0.5]
    if len(decided) == 0:
        return float("nan"), 0
    diff = predicted[decided[:, 0].astype(np.int64)] - predicted[decided[:, 1].astype(np.int64)]
    want = np.where(decided[:, 2] > 0.5, 1.0, -1.0)
    score = np.where(np.sign(diff) == want, 1.0, np.where(diff == 0, 0.5, 0.0))
    return float(score.mean()), int(len(decided))


def centred(values: np.ndarray, step: np.ndarray) -> np.ndarray:
    """values minus the mean of the values at the same step index; values, step: (n,)."""
    if len(values) == 0:
        return values
    sums = np.bincount(step, weights=values)
    counts = np.bincount(step)
    return values - (sums / np.maximum(counts, 1))[step]


def correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson's r of two equal-length arrays; NaN if either is constant or empty."""
    if len(x) < 2 or np.std(x) < 1e-12 or np.std(y) < 1e-12:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])
