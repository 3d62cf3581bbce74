"""Test metrics as the paper's tables define them.

return MSE: mean over test bags of (predicted return - true return)^2.
reward MSE: mean over all real steps of all test bags of (predicted r'_t - oracle r_t)^2.
Both in label units; `*_scaled` divide errors by the model's return_scale (Lunar Lander: 100).
"""

from __future__ import annotations

import torch

from ..datasets.trajectories import TrajectoryDataset
from .data import BagTensors
from .ensemble import MILEnsemble
from .models import MILRewardModel


@torch.no_grad()
def evaluate(model: MILRewardModel | MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> dict:
    """{"return_mse", "reward_mse", "bags"} of a model (an ensemble: of its mean prediction)."""
    if isinstance(model, MILEnsemble):
        return evaluate_ensemble(model, ds, batch_size)
    model.eval()
    bags = BagTensors(ds)
    scale = float(model.return_scale)
    ret_se, rew_se, steps = 0.0, 0.0, 0
    for start in range(0, len(bags), batch_size):
        index = torch.arange(start, min(start + batch_size, len(bags)))
        x, lengths, returns = bags.batch(index)
        out = model(x, lengths)
        ret_se += float(((out.returns - returns) ** 2).sum())
        mask = torch.arange(x.shape[1])[None, :] < lengths[:, None]
        true_rewards = bags.rewards[index, : x.shape[1]]
        rew_se += float((((out.rewards - true_rewards) ** 2) * mask).sum())
        steps += int(mask.sum())
    n = max(len(bags), 1)
    metrics = {"return_mse": ret_se / n, "reward_mse": rew_se / max(steps, 1), "bags": len(bags)}
    if scale != 1.0:
        metrics["return_mse_scaled"] = metrics["return_mse"] / scale ** 2
        metrics["reward_mse_scaled"] = metrics["reward_mse"] / scale ** 2
    return metrics


@torch.no_grad()
def evaluate_ensemble(ens: MILEnsemble, ds: TrajectoryDataset, batch_size: int = 512) -> dict:
    """Metrics of the ensemble-mean prediction (returns and rewards averaged over the members),
    plus the mean over bags of the members' return std ("return_std")."""
    ens.eval()
    bags = BagTensors(ds)
    ret_se, rew_se, steps, spread = 0.0, 0.0, 0, 0.0
    for start in range(0, len(bags), batch_size):
        index = torch.arange(start, min(start + batch_size, len(bags)))
        x, lengths, returns = bags.batch(index)
        out = ens(x, lengths)
        ret_se += float(((out.returns.mean(0) - returns) ** 2).sum())
        spread += float(out.returns.std(0, unbiased=False).sum())
        mask = torch.arange(x.shape[1])[None, :] < lengths[:, None]
        true_rewards = bags.rewards[index, : x.shape[1]]
        rew_se += float((((out.rewards.mean(0) - true_rewards) ** 2) * mask).sum())
        steps += int(mask.sum())
    n = max(len(bags), 1)
    metrics = {"return_mse": ret_se / n, "reward_mse": rew_se / max(steps, 1),
               "return_std": spread / n, "bags": len(bags)}
    scale = float(ens.return_scale)
    if scale != 1.0:
        metrics["return_mse_scaled"] = metrics["return_mse"] / scale ** 2
        metrics["reward_mse_scaled"] = metrics["reward_mse"] / scale ** 2
    return metrics
