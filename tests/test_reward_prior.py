"""The reward-sparsity prior (`reward_l1`) and the time-profile part of the reward MSE.

With bags of one length, rewards r_t + c * f(t) with sum_t f(t) = 0 give every bag the return of
r_t: the return loss cannot choose c. These tests check that the L1 term does (its minimum is at
c = 0 where most steps have no reward), and that `evaluate` reports such an error as its time
profile.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import evaluate, load_train_config
from nmrm_ros.mil.models import MILOutput
from nmrm_ros.mil.training import return_loss


@pytest.fixture(scope="module")
def key_bags():
    ds = generate_screened("key", 200, seed=0)
    assert set(ds.lengths.tolist()) == {100}  # the degeneracy needs equal lengths
    return ds


def _zero_sum_profile(T: int) -> torch.Tensor:
    f = torch.sin(torch.arange(T, dtype=torch.float64) * 2 * np.pi / T * 3)
    return f - f.mean()


class PlantedRewards:
    """Not a learnt model: the oracle's rewards plus c * f(t) (+ noise), to check the metric; shaped
    as an ensemble of one (outputs with a leading member axis)."""

    members = 1
    patch_layout = None  # no image

    def __init__(self, ds, c: float, noise: float = 0.0) -> None:
        self.rewards = torch.as_tensor(ds.rewards, dtype=torch.float64)
        self.c, self.noise = c, noise
        self.return_scale = torch.ones(())

    def eval(self):
        return self

    def __call__(self, x, lengths, patch_ordered=False):
        T = x.shape[1]
        assert x.shape[0] == len(self.rewards)  # one batch of every bag (batch_size >= n)
        r = self.rewards[:, :T] + self.c * _zero_sum_profile(T)
        if self.noise:
            r = r + self.noise * torch.as_tensor(np.random.default_rng(0).standard_normal(r.shape))
        return MILOutput(r.sum(1).float()[None], r.float()[None], x.new_zeros(1, x.shape[0], T, 0))


def test_time_profile_is_the_planted_zero_sum_error(key_bags):
    m = evaluate(PlantedRewards(key_bags, c=0.4), key_bags, batch_size=1000)
    planted = float(((0.4 * _zero_sum_profile(100)) ** 2).mean())
    assert m["return_mse"] < 1e-8  # invisible in the returns
    assert m["reward_mse"] == pytest.approx(planted, rel=1e-4)
    assert m["reward_mse_time_profile"] == pytest.approx(planted, rel=1e-4)
    noisy = evaluate(PlantedRewards(key_bags, c=0.0, noise=0.3), key_bags, batch_size=1000)
    assert noisy["reward_mse"] == pytest.approx(0.09, rel=0.05)
    assert noisy["reward_mse_time_profile"] < noisy["reward_mse"] / 50  # noise is not a time profile


def test_return_loss_formula():
    cfg = load_train_config("timer", reward_l1=0.05)
    assert cfg.reward_l1 == 0.05
    rewards = torch.tensor([[[1.0, -2.0, 0.0], [0.5, 0.5, 0.0]]])  # (K=1, B=2, T=3)
    out = MILOutput(rewards.sum(-1), rewards, torch.zeros(1, 2, 3, 0))
    labels = torch.tensor([[0.0, 2.0]])
    expected = ((-1.0 - 0.0) ** 2 + (1.0 - 2.0) ** 2) / 2 + 0.05 * (3.0 + 1.0) / 2
    assert float(return_loss(out, labels, cfg)[0]) == pytest.approx(expected)
    off = load_train_config("timer", reward_l1=0.0)
    assert float(return_loss(out, labels, off)[0]) == pytest.approx(1.0)


def test_l1_prior_picks_the_true_decomposition_among_equal_returns(key_bags):
    """Along r + c f(t) the return loss is flat; the L1 term is lowest at c = 0 (the oracle's),
    since at every step most Key bags get no reward."""
    rewards = torch.as_tensor(key_bags.rewards, dtype=torch.float32)[None]
    labels = torch.as_tensor(key_bags.returns, dtype=torch.float32)[None]
    assert float(((rewards[0] != 0).double().mean(0)).max()) < 0.5
    f = _zero_sum_profile(100).float()
    cfg = load_train_config("key", reward_l1=0.05)
    plain = load_train_config("key", reward_l1=0.0)
    cs = [-0.5, -0.2, -0.05, 0.0, 0.05, 0.2, 0.5]
    with_prior, without = [], []
    for c in cs:
        r = rewards + c * f
        out = MILOutput(r.sum(-1), r, torch.zeros(1, *r.shape[1:], 0))
        with_prior.append(float(return_loss(out, labels, cfg)[0]))
        without.append(float(return_loss(out, labels, plain)[0]))
    assert max(without) < 1e-6  # the returns cannot tell the decompositions apart
    assert int(np.argmin(with_prior)) == cs.index(0.0)
    assert all(a < b for a, b in zip(with_prior[3:], with_prior[4:]))  # grows away from c = 0
    assert all(a > b for a, b in zip(with_prior[:3], with_prior[1:4]))


def test_prefix_labels_see_the_credit_the_whole_returns_cannot(key_bags):
    """Cut half the bags at a random step (labels: the return earned by then): along r + c f(t) the
    return loss now grows with |c|, so it tells the oracle's decomposition (c = 0) from the others."""
    from nmrm_ros.datasets import cut_episodes

    cut = cut_episodes(key_bags, 0.5, seed=0)
    labels = torch.as_tensor(cut.returns, dtype=torch.float32)[None]
    live = torch.as_tensor(np.arange(100)[None, :] < cut.lengths[:, None])
    plain = load_train_config("key", reward_l1=0.0)
    losses = []
    for c in (0.0, 0.05, 0.2, 0.5):
        r = (torch.as_tensor(key_bags.rewards, dtype=torch.float32) + c * _zero_sum_profile(100).float()) * live
        out = MILOutput(r.sum(-1)[None], r[None], torch.zeros(1, *r.shape, 0))
        losses.append(float(return_loss(out, labels, plain)[0]))
    assert losses[0] < 1e-8 and all(a < b for a, b in zip(losses, losses[1:]))


def test_prefix_fraction_trains_on_prefixes_and_tests_on_whole_episodes(key_bags):
    from nmrm_ros.datasets import cut_episodes
    from nmrm_ros.mil.data import split_indices
    from nmrm_ros.mil.pipeline import fit

    cfg = load_train_config("key", prefix_fraction=0.5, max_epochs=1, members=1)
    run = fit(key_bags, "csc_lstm", cfg, progress=False)
    _, val, test = split_indices(len(key_bags), 0)
    whole = evaluate(run.model, key_bags.subset(test))
    assert run.test_metrics["return_mse"] == pytest.approx(whole["return_mse"])
    cut = evaluate(run.model, cut_episodes(key_bags, 0.5, seed=cfg.seed).subset(val))
    assert run.val_metrics["return_mse"] == pytest.approx(cut["return_mse"])
    with pytest.raises(ValueError, match="prefix_fraction"):
        load_train_config("key", prefix_fraction=0.5, feedback="preferences")
    with pytest.raises(ValueError, match="prefix_fraction"):
        load_train_config("key", prefix_fraction=1.5)


def test_preferences_drop_a_tasks_prefix_labels():
    """Lunar Lander's config cuts half the return-labelled episodes (prefix_fraction 0.5); trained
    from comparisons it simply does not, instead of refusing its own default."""
    assert load_train_config("lunar_lander").prefix_fraction == 0.5
    assert load_train_config("lunar_lander", feedback="preferences").prefix_fraction == 0.0
    assert load_train_config("lunar_lander", feedback="both").prefix_fraction == 0.0
    with pytest.raises(ValueError, match="prefix_fraction"):
        load_train_config("lunar_lander", feedback="preferences", prefix_fraction=0.5)
