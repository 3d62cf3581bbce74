"""Initialisation settings of training (nmrm_ros.mil.training): the ReLU bias that keeps the toy
models' two feature units alive, the LSTM forget-gate bias, and that a warm start keeps both."""

import numpy as np
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.mil import load_train_config, model_config
from nmrm_ros.mil.data import normalisation, split_indices
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.training import init_relu_bias, train_ensemble


def _active_fraction(ens, ds, train) -> np.ndarray:
    """Per feature unit of member 0: the fraction of real training instances it is > 0 on."""
    model = ens.member(0)
    shift, scale = normalisation(ds.subset(train), "standard")
    real = np.arange(ds.states.shape[1])[None, :] < ds.lengths[train][:, None]
    x = torch.as_tensor((ds.states[train][real] - shift) / scale, dtype=torch.float32)
    with torch.no_grad():
        z = model.feature_extractor[0](x)
    return (z > 0).float().mean(0).numpy()


def test_a_toy_seed_starts_with_a_dead_relu_unit_and_relu_bias_revives_it():
    """Dial repeat 4 (weight seed 4, split 4), one of the CSC runs that stayed on the plateau: with
    torch's init one of its two feature units is 0 on every training instance, so it never gets a
    gradient; with relu_bias 1 both units are active on most instances."""
    ds = make_toy_dataset("dial", 5000, seed=0)
    train, _, _ = split_indices(len(ds), 4)
    config = model_config("csc_lstm", "dial", 2)
    default = _active_fraction(init_ensemble(config, [4]), ds, train)
    assert default.min() == 0.0 and default.max() > 0.1, default
    ens = init_ensemble(config, [4])
    init_relu_bias(ens, 1.0)
    assert _active_fraction(ens, ds, train).min() > 0.5


def test_relu_bias_sets_only_the_layers_a_relu_follows():
    ens = init_ensemble(model_config("csc_lstm", "key", 2, dropout=0.1), [0, 1])
    before = {k: v.detach().clone() for k, v in ens.params.items()}
    init_relu_bias(ens, 0.25)
    changed = {k for k in before if not torch.equal(before[k], ens.params[k])}
    assert changed == {"feature_extractor__0__bias", "feature_extractor__3__bias", "feature_extractor__6__bias",
                       "head__0__bias", "head__3__bias"}  # FC layers at 0, 3, 6: FC, ReLU, dropout
    assert all(torch.all(ens.params[k] == 0.25) for k in changed)


def test_a_warm_start_keeps_its_trained_initial_biases():
    """train_ensemble applies lstm_forget_bias and relu_bias to a fresh ensemble only: a warm start
    (the trainer node's retraining) keeps the weights it was given."""
    ds = make_toy_dataset("dial", 200, seed=0)
    train, val, _ = split_indices(len(ds), 0)
    cfg = load_train_config("dial", max_epochs=1, lstm_forget_bias=1.0, relu_bias=1.0)
    cfg.lr = 0.0  # no update (a setting `load_train_config` refuses: set here on purpose)
    k = 2
    for fresh, forget, relu in ((True, 1.0, 1.0), (False, 5.0, 3.0)):
        ens = init_ensemble(model_config("csc_lstm", "dial", 2), [0])
        with torch.no_grad():
            ens.params["lstm__bias_ih_l0"][:, k:2 * k] = 5.0
            ens.params["feature_extractor__0__bias"].fill_(3.0)
        train_ensemble(ens, ds, [(train, val)], cfg, progress=False, fresh=fresh)  # lr 0: no update
        assert torch.all(ens.params["lstm__bias_ih_l0"][:, k:2 * k] == forget)
        assert torch.all(ens.params["feature_extractor__0__bias"] == relu)
