"""Test metrics as the paper's tables define them.

return MSE: mean over test bags of (predicted return - true return)^2.
reward MSE: mean over all real steps of all test bags of (predicted r'_t - oracle r_t)^2.
Both in label units; `*_scaled` divide errors by the model's return_scale (Lunar Lander: 100).
reward MSE, time profile: the part of the reward MSE that is the mean error at each step index t
over the bags (sum over t of n_t * mean_error_t^2 / steps; the rest is the spread of the errors
around that mean). A model that fits the returns but adds a zero-sum function of time to every
bag's rewards (invisible in the returns when all bags are equal in length) shows its error here.
"""

from __future__ import annotations

import torch

from ..datasets.trajectories import TrajectoryDataset
from .data import BagTensors
from .ensemble import MILEnsemble
from .models import MILRewardModel


@torch.no_grad()
def evaluate(model: MILRewardModel | MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> dict:
    """{"return_mse", "reward_mse", "bags"} of a model. An ensemble is scored on its mean
    prediction (returns and rewards averaged over the members), and "return_std" adds the mean
    over bags of the members' return std."""
    ensemble = isinstance(model, MILEnsemble)
    model.eval()
    bags = BagTensors(ds)
    ret_se, rew_se, steps, spread = 0.0, 0.0, 0, 0.0
    err_by_t = torch.zeros(bags.x.shape[1], dtype=torch.float64)  # summed errors per step index
    n_by_t = torch.zeros(bags.x.shape[1], dtype=torch.float64)
    for start in range(0, len(bags), batch_size):
        index = torch.arange(start, min(start + batch_size, len(bags)))
        x, lengths, returns = bags.batch(index)
        out = model(x, lengths)
        pred_returns, pred_rewards = out.returns, out.rewards
        if ensemble:
            spread += float(pred_returns.std(0, unbiased=False).sum())
            pred_returns, pred_rewards = pred_returns.mean(0), pred_rewards.mean(0)
        ret_se += float(((pred_returns - returns) ** 2).sum())
        mask = torch.arange(x.shape[1])[None, :] < lengths[:, None]
        true_rewards = bags.rewards[index, : x.shape[1]]
        err = (pred_rewards - true_rewards) * mask
        rew_se += float((err ** 2).sum())
        steps += int(mask.sum())
        err_by_t[: x.shape[1]] += err.double().sum(0)
        n_by_t[: x.shape[1]] += mask.double().sum(0)
    n = max(len(bags), 1)
    profile = float((err_by_t ** 2 / n_by_t.clamp(min=1)).sum()) / max(steps, 1)
    metrics = {"return_mse": ret_se / n, "reward_mse": rew_se / max(steps, 1),
               "reward_mse_time_profile": profile, "bags": len(bags)}
    if ensemble:
        metrics["return_std"] = spread / n
    scale = float(model.return_scale)
    if scale != 1.0:
        metrics["return_mse_scaled"] = metrics["return_mse"] / scale ** 2
        metrics["reward_mse_scaled"] = metrics["reward_mse"] / scale ** 2
        metrics["reward_mse_time_profile_scaled"] = profile / scale ** 2
    return metrics
