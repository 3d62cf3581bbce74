"""MIL models: shapes, masking, online stepping = batched forward, checkpoints, normalisation."""

import json

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.mil import (ARCHITECTURES, CheckpointError, OnlineRewardModel, build_model,
                          load_checkpoint, load_train_config, model_config, Run,
                          train_model)
from nmrm_ros.mil.data import normalisation, split_indices
from nmrm_ros.mil.models import OUTPUT_ACTIVATIONS
from nmrm_ros.mil.online import batched_reference


def _model(arch, task="key", d=2, seed=0):
    torch.manual_seed(seed)
    model = build_model(model_config(arch, task, d, dropout=0.1))
    # non-trivial normalisation and initial state so the test exercises them
    model.set_normalisation(torch.full((d,), 0.3), torch.full((d,), 0.7), 1.0)
    if model.uses_lstm:
        with torch.no_grad():
            model.h0.uniform_(-0.5, 0.5)
            model.c0.uniform_(-0.5, 0.5)
    return model.eval()


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_shapes_masking_and_sum(arch):
    model = _model(arch)
    x = torch.rand(3, 12, 2)
    lengths = torch.tensor([12, 5, 1])
    out = model(x, lengths)
    k = {"instance_nn": 0, "transformer": 8}.get(arch, 2)  # the transformer is at least 8 wide
    assert out.returns.shape == (3,) and out.rewards.shape == (3, 12) and out.hidden.shape == (3, 12, k)
    assert torch.all(out.rewards[1, 5:] == 0) and torch.all(out.rewards[2, 1:] == 0)
    torch.testing.assert_close(out.rewards.sum(1), out.returns, rtol=1e-5, atol=1e-5)
    # padding does not change what comes before it (the models are causal)
    short = model(x[1:2, :5], lengths[1:2])
    torch.testing.assert_close(short.rewards[0], out.rewards[1, :5])


@pytest.mark.parametrize("arch", ARCHITECTURES)
@pytest.mark.parametrize("task,d", [("key", 2), ("lunar_lander", 8), ("push_switch", 2)])
def test_online_step_equals_batched_forward(arch, task, d):
    model = _model(arch, task, d)
    states = np.random.default_rng(1).normal(size=(60, d)).astype(np.float32)
    rewards, hidden = batched_reference(model, states)
    online = OnlineRewardModel(model)
    for _ in range(2):  # reset gives the same trajectory again
        online.reset()
        for t in range(len(states)):
            r, h = online.step(states[t])
            assert r == pytest.approx(rewards[t], abs=1e-5)
            np.testing.assert_allclose(h, hidden[t], atol=1e-6)


def test_online_step_rejects_bad_states():
    online = OnlineRewardModel(_model("csc_lstm"))
    with pytest.raises(ValueError, match="size 2"):
        online.step(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        online.step(np.array([np.nan, 0.0]))


def test_embedding_lstm_rewards_telescope_to_partial_returns():
    model = _model("embedding_lstm")
    x = torch.rand(1, 8, 2)
    out = model(x, torch.tensor([8]))
    for t in (1, 4, 8):
        prefix = model(x[:, :t], torch.tensor([t]))
        torch.testing.assert_close(out.rewards[0, :t].sum(), prefix.returns[0], rtol=1e-5, atol=1e-5)


def test_normalisation_uses_training_split_only():
    ds = make_toy_dataset("dial", 400, seed=0)
    train, val, test = split_indices(len(ds), seed=3)
    assert len(set(train) | set(val) | set(test)) == len(ds) and len(train) == 320
    ds.states[test] += 100.0  # a shifted test split must not move the statistics
    cfg = load_train_config("dial", max_epochs=1)
    model = build_model(model_config("csc_lstm", "dial", 2))
    train_model(model, ds.subset(train), ds.subset(val), cfg, progress=False)
    shift, scale = normalisation(ds.subset(train))
    np.testing.assert_allclose(model.input_shift.numpy(), shift, rtol=1e-6)
    np.testing.assert_allclose(model.input_scale.numpy(), scale, rtol=1e-6)
    assert abs(model.input_shift.numpy()).max() < 1.0


def test_checkpoint_round_trip_and_refusals(tmp_path):
    model = _model("csc_lstm")
    path = Run.of(model, "key", seed=0, metrics={"x": 1.0}).save(tmp_path / "key_csc")
    loaded, meta = load_checkpoint(path, architecture="csc_lstm", input_size=2, task="key")
    assert meta.task == "key" and meta.metrics == {"x": 1.0}
    x = torch.rand(2, 10, 2)
    # a single model is saved and loaded as an ensemble of one
    assert loaded.members == 1 and meta.ensemble.members == 1
    torch.testing.assert_close(loaded(x, torch.tensor([10, 7])).rewards[0],
                               model(x, torch.tensor([10, 7])).rewards)
    with pytest.raises(CheckpointError, match="csc_lstm model, not the requested instance_lstm"):
        load_checkpoint(path, architecture="instance_lstm")
    with pytest.raises(CheckpointError, match="size 2, not 8"):
        load_checkpoint(path, input_size=8)
    with pytest.raises(CheckpointError, match="task 'key', not 'timer'"):
        load_checkpoint(path, task="timer")
    with pytest.raises(CheckpointError, match="missing"):
        load_checkpoint(tmp_path / "nothing")
    # weights that do not match their metadata
    meta_path = path.with_suffix(".json")
    record = json.loads(meta_path.read_text())
    record["model"]["fe_sizes"] = [16, 8, 8]
    meta_path.write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match="do not match their metadata"):
        load_checkpoint(path)
    meta_path.write_text("{ not json")
    with pytest.raises(CheckpointError, match="malformed"):
        load_checkpoint(path)
    path.write_bytes(b"garbage")
    meta_path.write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match="do not belong to"):  # the .json holds the .pt's hash
        load_checkpoint(path)
    record.pop("weights_sha256")  # a checkpoint from before the hash: the weights are read
    meta_path.write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match="cannot read"):
        load_checkpoint(path)


def test_format_1_metadata_loads_typed_and_is_written_back_as_format_2(tmp_path):
    """A checkpoint of format 1 (the data source a string, written until 2026-12-05) loads with its
    data source typed (regenerable as before); unknown entries survive a saved copy; a source no
    code can make again (bench/preferences wrote none) says so."""
    from nmrm_ros.mil import DataSource, Run
    from nmrm_ros.mil.checkpoint import FORMAT, DataInfo

    path = Run.of(_model("csc_lstm"), "key", seed=3).save(tmp_path / "new")
    record = json.loads(path.with_suffix(".json").read_text())
    assert record["format"] == FORMAT and record["data"]["source"]["kind"] == ""
    record.update(format="nmrm_ros.mil_checkpoint/1", mapped={"a": 2.0},
                  data={"source": "toy:key:n=100:seed=4", "n": 100, "meta": {"seed": 4}})
    path.with_suffix(".json").write_text(json.dumps(record))
    run = Run.load(path)
    assert run.meta.data.source == DataSource("toy", "key", 100, 4) and run.meta.data.source.regenerable
    assert str(run.meta.data.source) == "toy:key:n=100:seed=4" and run.meta.extra == {"mapped": {"a": 2.0}}
    copy = json.loads(run.replace(calibration={"gain": [1.0]}).save(tmp_path / "copy").with_suffix(".json").read_text())
    assert copy["format"] == FORMAT and copy["mapped"] == {"a": 2.0} and copy["seed"] == 3
    assert Run.load(tmp_path / "copy").meta.data == DataInfo(DataSource("toy", "key", 100, 4), 100, {"seed": 4})
    for text, kind in (("bags:a,b", "bags"), ("runs/x.npz", "file"), ("live labels", "live"),
                       ("screened:gym:CartPole-v1:n=100:seed=0", "screened"), ("my.data", "file"), ("", "")):
        source = DataSource.parse(text)
        assert source.kind == kind and str(source) == text
    assert DataSource.parse("screened:gym:CartPole-v1:n=100:seed=0").task == "gym:CartPole-v1"
    assert not DataSource.parse("").regenerable and str(DataSource("file")) == ""
    record["ensemble"]["future"] = 1  # entries a later version adds survive a copy
    path.with_suffix(".json").write_text(json.dumps(record))
    assert json.loads(Run.load(path).save(tmp_path / "again").with_suffix(".json").read_text())["ensemble"]["future"] == 1
    record["format"] = "nmrm_ros.mil_checkpoint/9"
    path.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match="unknown checkpoint format"):
        Run.load(path)


def test_a_single_model_checkpoint_from_before_ensembles_of_one_loads(tmp_path):
    """Checkpoints written before every model became an ensemble (a MILRewardModel's state dict,
    no "ensemble" entry) load as an ensemble of one computing the same."""
    import hashlib

    model = _model("csc_lstm")
    weights = tmp_path / "old.pt"
    torch.save(model.state_dict(), weights)
    (tmp_path / "old.json").write_text(json.dumps({
        "format": "nmrm_ros.mil_checkpoint/1", "task": "key", "model": model.config.to_dict(),
        "weights_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(),
        "normalisation": {"shift": model.input_shift.tolist(), "scale": model.input_scale.tolist(),
                          "return_scale": float(model.return_scale)}}))
    loaded, meta = load_checkpoint(weights, task="key")
    assert loaded.members == 1 and meta.ensemble.members == 1 and meta.ensemble.seeds is None
    x = torch.rand(3, 9, 2)
    torch.testing.assert_close(loaded(x, torch.tensor([9, 4, 1])).rewards[0],
                               model(x, torch.tensor([9, 4, 1])).rewards)


def test_unknown_architecture():
    with pytest.raises(ValueError, match="unknown architecture"):
        model_config("gru", "key", 2)


@pytest.mark.parametrize("activation", OUTPUT_ACTIVATIONS)
def test_output_activations_agree_online_batched_and_ensembled(activation):
    """Each output activation is computed alike by the model, an ensemble of it and the online
    stepper; leaky_relu and softplus keep rewards (almost) non-negative."""
    torch.manual_seed(3)
    model = build_model(model_config("csc_lstm", "lunar_lander", 8, output_activation=activation)).eval()
    states = np.random.default_rng(2).normal(size=(40, 8)).astype(np.float32)
    rewards, _ = batched_reference(model, states)
    with torch.no_grad():
        single = model(torch.as_tensor(states)[None], torch.tensor([40])).rewards[0].double().numpy()
    np.testing.assert_allclose(rewards, single, rtol=1e-5, atol=1e-6)  # the ensemble of one = the model
    online = OnlineRewardModel(model)
    np.testing.assert_allclose([online.step(s)[0] for s in states], rewards, rtol=1e-5, atol=1e-6)
    if activation != "none":
        assert rewards.min() > -1e-4
    with pytest.raises(ValueError, match="unknown output activation"):
        model_config("csc_lstm", "lunar_lander", 8, output_activation="tanh")


def test_layer_widths_of_a_training_config_reach_the_model_the_checkpoint_and_the_stepper(tmp_path):
    """fe_sizes / head_sizes of a training config (config/mil_training.yaml, `nmrm train
    --fe-sizes/--head-sizes`) replace the family's widths; unset, the family's stand."""
    from nmrm_ros.mil import Run, load_train_config

    cfg = load_train_config("key", fe_sizes="8,4", head_sizes="")
    config = cfg.model_config("csc_lstm", "key", 4)
    assert (config.fe_sizes, config.head_sizes) == ((8, 4), ())
    assert load_train_config("key").model_config("csc_lstm", "key", 4).fe_sizes == (64, 32, 32)
    torch.manual_seed(0)
    model = build_model(config).eval()
    Run.of(model, "key").save(tmp_path / "m")
    loaded, _ = load_checkpoint(tmp_path / "m")
    assert (loaded.config.fe_sizes, loaded.config.head_sizes) == ((8, 4), ())
    states = np.random.default_rng(0).normal(size=(30, 4)).astype(np.float32)
    rewards, _ = batched_reference(loaded, states)
    online = OnlineRewardModel(loaded)
    np.testing.assert_allclose([online.step(s)[0] for s in states], rewards, rtol=1e-5, atol=1e-6)
