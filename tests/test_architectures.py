"""The architecture registry: one rule per architecture, its batched form equal to its step form,
and a fifth architecture added by a registry entry alone reaching training, the ensemble, the
online stepper and the served state."""

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.mil import (ARCHITECTURE_NAMES, ARCHITECTURES, OnlineRewardModel, load_train_config,
                          model_config)
from nmrm_ros.mil.architectures import (REGISTRY, CSCInstanceSpaceLSTM, EmbeddingSpaceLSTM,
                                        architecture)
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.online import batched_reference
from nmrm_ros.mil.served_state import served_states
from nmrm_ros.mil.training import train_ensemble


def test_the_registry_is_the_list_of_architectures():
    assert ARCHITECTURES == ("instance_nn", "embedding_lstm", "instance_lstm", "csc_lstm", "transformer")
    assert ARCHITECTURE_NAMES["csc_lstm"] == "CSC Instance Space LSTM"
    with pytest.raises(ValueError, match="unknown architecture 'gru'; known: instance_nn, "):
        architecture("gru")
    with pytest.raises(ValueError, match="unknown architecture 'gru'"):
        model_config("gru", "key", 2)


@pytest.mark.parametrize("name", ARCHITECTURES)
def test_step_rule_equals_batched_rule(name):
    """`step_rewards` carried along a bag gives `outputs`' rewards, and their sum its return."""
    arch = REGISTRY[name]
    y = torch.randn(4, 9, dtype=torch.float64)
    lengths = torch.tensor([9, 4, 1, 0])
    mask = (torch.arange(9)[None] < lengths[:, None]).double()
    returns, rewards = arch.outputs(y, mask, lengths)
    for b, n in enumerate(lengths.tolist()):
        carry, total = np.zeros(()), 0.0
        for t in range(n):
            r, carry = arch.step_rewards(y[b, t].numpy(), carry)
            assert float(r) == pytest.approx(float(rewards[b, t]), abs=1e-12)
            total += float(r)
        assert float(returns[b]) == pytest.approx(total, abs=1e-9)
        assert torch.all(rewards[b, n:] == 0)


class _CSCPartialReturns(EmbeddingSpaceLSTM):
    """Not a paper architecture: the CSC head's input, read as partial returns."""

    name = "csc_partial_returns"
    head_input_size = CSCInstanceSpaceLSTM.head_input_size
    head_input = CSCInstanceSpaceLSTM.head_input


def test_a_new_architecture_is_one_registry_entry(monkeypatch):
    monkeypatch.setitem(REGISTRY, _CSCPartialReturns.name, _CSCPartialReturns())
    config = model_config(_CSCPartialReturns.name, "key", 2)
    ens = init_ensemble(config, [0, 1]).eval()
    assert ens.member(0).head_input_size == config.fe_sizes[-1] + config.hidden_size
    states = np.random.default_rng(0).normal(size=(30, 2)).astype(np.float32)
    out = ens(torch.as_tensor(states)[None], torch.tensor([30]))
    # the rule reached the ensemble: rewards are differences of partial returns, summing to the last
    torch.testing.assert_close(out.rewards.sum(-1), out.returns, rtol=1e-5, atol=1e-5)
    for m in range(2):  # each member's own forward is the ensemble's
        alone = ens.member(m)(torch.as_tensor(states)[None], torch.tensor([30]))
        torch.testing.assert_close(alone.rewards[0], out.rewards[m, 0], rtol=1e-5, atol=1e-6)
    rewards, served = batched_reference(ens, states)
    online = OnlineRewardModel(ens)
    for t, s in enumerate(states):
        r, h = online.step(s)
        assert r == pytest.approx(rewards[t], abs=1e-5)
        np.testing.assert_allclose(h, served[t], atol=1e-5)
    np.testing.assert_allclose(online.episode_rewards(states), rewards, atol=1e-5)  # from a fresh start
    assert served_states(ens, states[None]).shape == (1, 30, 2 * config.hidden_size)
    # and training: the members' losses fall through the new rule
    ds = make_toy_dataset("push_switch", n_bags=200, seed=0)
    cfg = load_train_config("push_switch", max_epochs=10, patience=10)
    ens = init_ensemble(model_config(_CSCPartialReturns.name, "push_switch", ds.state_size), [0, 1])
    result = train_ensemble(ens, ds, [(np.arange(160), np.arange(160, 200))] * 2, cfg, progress=False)
    first, last = result.history[0]["train_loss"], result.history[-1]["train_loss"]
    assert all(b < 0.8 * a for a, b in zip(first, last)), (first, last)


def test_the_transformer_is_causal_and_served_step_by_step_past_its_time_code():
    """The fifth architecture: z_t sees f_0..f_t only; stepped online (keys and values cached, the
    time code extended past its first 1024 steps) it equals the batched forward; it serves z_t,
    k values in [-1, 1], whatever the served kind."""
    config = model_config("transformer", "key", 2)
    assert config.hidden_size == 8  # at least 8 wide, whatever the task's LSTM size
    ens = init_ensemble(config, [0, 1]).eval()
    states = np.random.default_rng(1).normal(size=(1100, 2)).astype(np.float32)
    with torch.no_grad():
        full = ens(torch.as_tensor(states)[None], torch.tensor([1100]))
        changed = states.copy()
        changed[600:] += 5.0  # the future changes: the past does not
        other = ens(torch.as_tensor(changed)[None], torch.tensor([1100]))
    torch.testing.assert_close(other.rewards[..., :600], full.rewards[..., :600])
    assert not torch.allclose(other.rewards[..., 600:], full.rewards[..., 600:])
    rewards, served = batched_reference(ens, states)
    for kind in ("h_tanh_c", "h"):
        online = OnlineRewardModel(ens, served=kind)
        assert online.served_size == 8
        stepped = [online.step(s) for s in states]
        np.testing.assert_allclose([r for r, _ in stepped], rewards, atol=1e-4)
        np.testing.assert_allclose(np.stack([h for _, h in stepped]), served, atol=1e-4)
    assert served.shape == (1100, 8) and np.abs(served).max() <= 1.0
