"""The plateau schedule (nmrm_ros.mil.training): training stops on convergence, not at an epoch
cap, and each member of an ensemble keeps its own learning-rate factor, so it still trains exactly
as it would alone."""

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.mil import load_train_config, model_config
from nmrm_ros.mil.data import split_indices
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.training import scaled_step, train_ensemble


def test_a_toy_run_stops_on_convergence_before_its_cap():
    ds = make_toy_dataset("toggle_switch", 600, seed=0)
    train, val, _ = split_indices(len(ds), 0)
    cfg = load_train_config("toggle_switch", schedule="plateau", max_epochs=1000, plateau_patience=3,
                            patience=1000, min_lr_ratio=0.05, plateau_factor=0.5)
    ens = init_ensemble(model_config("csc_lstm", "toggle_switch", 2), [0])
    result = train_ensemble(ens, ds, [(train, val)], cfg, progress=False)
    factors = [h["lr_factor"][0] for h in result.history]
    assert result.epochs_run < 200, result.epochs_run  # converged long before the cap
    assert result.still_improving == [False]
    assert factors[-1] == 0.0  # done: the factor fell below min_lr_ratio
    cuts = sorted({f for f in factors if f > 0}, reverse=True)
    assert cuts[:5] == pytest.approx([1.0, 0.5, 0.25, 0.125, 0.0625])  # halved at each plateau


def test_scaled_step_scales_each_members_adam_update():
    torch.manual_seed(0)
    w = torch.nn.Parameter(torch.randn(3, 4, 2))
    start = w.detach().clone()
    opt = torch.optim.Adam([w], lr=1e-2)
    (w ** 2).sum().backward()
    reference = torch.optim.Adam([torch.nn.Parameter(start.clone())], lr=1e-2)
    ref_param = reference.param_groups[0]["params"][0]
    ref_param.grad = w.grad.clone()
    reference.step()
    scaled_step(opt, [w], torch.tensor([1.0, 0.5, 0.0], dtype=torch.float64))
    torch.testing.assert_close(w[0], ref_param[0])
    torch.testing.assert_close(w[1] - start[1], 0.5 * (ref_param[1] - start[1]))
    torch.testing.assert_close(w[2], start[2])  # factor 0: frozen


def test_each_member_of_a_plateau_ensemble_trains_as_it_would_alone():
    ds = make_toy_dataset("push_switch", 400, seed=1)
    splits = [split_indices(len(ds), s)[:2] for s in (0, 1)]
    cfg = load_train_config("push_switch", schedule="plateau", max_epochs=40, plateau_patience=2,
                            min_lr_ratio=0.01)
    config = model_config("instance_lstm", "push_switch", 2)
    both = init_ensemble(config, [0, 1])
    together = train_ensemble(both, ds, splits, cfg, seeds=[0, 1], progress=False)
    alone = init_ensemble(config, [1])
    single = train_ensemble(alone, ds, splits[1:], cfg, seeds=[1], progress=False)
    assert together.best_epochs[1] == single.best_epochs[0]
    assert [h["lr_factor"][1] for h in together.history][:single.epochs_run] == \
        [h["lr_factor"][0] for h in single.history]
    np.testing.assert_allclose(together.best_val_loss[1], single.best_val_loss[0], rtol=1e-4)


def test_only_progress_by_min_improvement_resets_the_clocks():
    """With min_improvement 0.2 an epoch counts as progress only when its validation loss is 20%
    below the last progress epoch's: the run stops `patience` epochs after its last progress even
    while it still creeps down, and keeps its best weights all the same."""
    ds = make_toy_dataset("toggle_switch", 400, seed=0)
    train, val, _ = split_indices(len(ds), 0)
    base = dict(schedule="constant", max_epochs=60, patience=5)
    config = model_config("csc_lstm", "toggle_switch", 2)
    strict = train_ensemble(init_ensemble(config, [0]), ds, [(train, val)],
                            load_train_config("toggle_switch", min_improvement=0.2, **base), progress=False)
    losses = [h["val_loss"][0] for h in strict.history]
    last, progress = np.inf, []
    for epoch, loss in enumerate(losses, start=1):
        if loss < last * 0.8:
            last, progress = loss, progress + [epoch]
    assert strict.epochs_run == progress[-1] + 5  # 5 epochs past the last 20% step, not past the best
    assert strict.best_val_loss[0] == pytest.approx(min(losses))  # the best weights: any improvement
    with pytest.raises(ValueError, match="min_improvement"):
        load_train_config("toggle_switch", min_improvement=1.0)


def test_members_that_are_done_are_not_computed():
    """Once a plateau member is done (factor 0) the training forward leaves it out, and the others
    train as they did with it (same best epochs as each trained alone)."""
    ds = make_toy_dataset("push_switch", 400, seed=1)
    splits = [split_indices(len(ds), s)[:2] for s in (0, 1, 2)]
    cfg = load_train_config("push_switch", schedule="plateau", max_epochs=60, plateau_patience=2, min_lr_ratio=0.05)
    config = model_config("csc_lstm", "push_switch", 2)
    ens = init_ensemble(config, [0, 1, 2])
    computed = []
    forward = ens.forward

    def counting(x, lengths, members=None, patch_ordered=False):
        if ens.training:
            computed.append(3 if members is None else len(members))
        return forward(x, lengths, members, patch_ordered)

    ens.forward = counting
    result = train_ensemble(ens, ds, splits, cfg, seeds=[0, 1, 2], progress=False)
    done = sorted(next((h["epoch"] for h in result.history if h["lr_factor"][m] == 0), 10 ** 6) for m in range(3))
    assert done[-1] <= result.epochs_run, done  # every member was done within the limit
    assert done[0] < done[-1] and min(computed) < 3  # members finished apart, and were left out
    assert result.history[done[0]]["train_loss"].count(None) >= 1  # and have no training loss then
    steps = len(computed) // result.epochs_run
    assert computed[done[0] * steps] < 3  # from the epoch after the first one was done
    for m in range(3):
        alone = train_ensemble(init_ensemble(config, [m]), ds, splits[m:m + 1], cfg, seeds=[m], progress=False)
        assert alone.best_epochs[0] == result.best_epochs[m]
