"""Calibration (`nmrm calibrate`, nmrm_ros.mil.calibration): a few return labels give a model of
comparisons the units of returns, without changing how it orders episodes."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import torch

from nmrm_ros.testing.graph import executable
from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.datasets.trajectories import TrajectoryDataset
from nmrm_ros.mil import Run, evaluate, load_checkpoint
from nmrm_ros.mil.calibration import CalibrationError, calibrate, fit_calibration, step_units
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.models import model_config


def _predicted(model, ds) -> np.ndarray:
    with torch.no_grad():
        out = model(torch.as_tensor(ds.states, dtype=torch.float32), torch.as_tensor(ds.lengths))
    return out.returns.double().numpy(), out.rewards.double().numpy()


def _labelled_by(model, ds, gain: float, bias: float, member: int = 0) -> TrajectoryDataset:
    """ds with return labels such that member `member` predicts gain * label + bias per step."""
    returns = (_predicted(model, ds)[0][member] - bias * ds.lengths) / gain
    return TrajectoryDataset(ds.task, ds.states, ds.lengths, returns, ds.rewards, ds.hidden, meta=ds.meta)


@pytest.mark.parametrize("arch", ["csc_lstm", "instance_nn"])
def test_calibration_recovers_gain_and_per_step_bias_and_keeps_the_order(arch):
    ds = make_toy_dataset("push_switch", 200, seed=0)
    model = init_ensemble(model_config(arch, "push_switch", ds.state_size), [0, 0]).eval()
    last = model._head[-1]
    with torch.no_grad():  # member 1 predicts twice what member 0 does
        model.params[f"head__{last}__weight"][1] *= 2
        model.params[f"head__{last}__bias"][1] *= 2
    labelled = _labelled_by(model, ds, gain=3.0, bias=0.1)
    fit = fit_calibration(model, labelled)
    assert fit.labels == 200
    np.testing.assert_allclose(fit.gain, [3.0, 6.0], rtol=1e-5)
    np.testing.assert_allclose(fit.bias, [0.1, 0.2], atol=1e-5)
    calibrated = calibrate(model, fit)
    returns, rewards = _predicted(calibrated, labelled)
    np.testing.assert_allclose(returns[0], labelled.returns, atol=1e-4)
    # per step: (r' - bias) / gain, member by member
    before = _predicted(model, labelled)[1]
    mask = np.arange(ds.states.shape[1])[None] < ds.lengths[:, None]
    for m in range(2):
        np.testing.assert_allclose(rewards[m][mask], ((before[m] - fit.bias[m]) / fit.gain[m])[mask], atol=1e-5)
    a, b = evaluate(model, labelled), evaluate(calibrated, labelled)
    assert b["preference_accuracy"] == 1.0 and b["return_mse"] < 1e-6 < a["return_mse"]
    # among episodes of one length the order, and so every scale-free metric, is unchanged
    length = np.bincount(ds.lengths).argmax()
    same = labelled.subset(np.flatnonzero(ds.lengths == length))
    assert len(same) > 20
    assert np.array_equal(np.argsort(_predicted(model, same)[0][1]), np.argsort(_predicted(calibrated, same)[0][1]))


def test_a_model_of_comparisons_is_put_in_units_of_its_largest_step():
    """Comparisons leave the scale free: fit serves such a model with rewards r'_t / (the largest
    |r'_t| of its members' mean on the dataset's steps), one gain for all members, so the mean's
    order is unchanged; a model of returns is left as it is; a warm start undoes the gain."""
    from nmrm_ros.mil.pipeline import in_step_units

    ds = make_toy_dataset("push_switch", 200, seed=0)
    model = init_ensemble(model_config("csc_lstm", "push_switch", ds.state_size), [0, 1]).eval()
    last = model._head[-1]
    with torch.no_grad():  # member 1 pays on a scale 5x member 0's
        model.params[f"head__{last}__weight"][1] *= 5
        model.params[f"head__{last}__bias"][1] *= 5
    mask = np.arange(ds.states.shape[1])[None] < ds.lengths[:, None]
    before = _predicted(model, ds)[1]
    units = step_units(model, ds)
    largest = np.abs(before.mean(0)[mask]).max()
    np.testing.assert_allclose(units.gain, [largest, largest], rtol=1e-5)
    scaled, record = in_step_units(model, ds, "preferences")
    after = _predicted(scaled, ds)[1]
    assert np.abs(after.mean(0)[mask]).max() == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_allclose(after[1][mask], before[1][mask] / largest, rtol=1e-4, atol=1e-6)
    assert record["step_units"]["largest_step_reward"] == pytest.approx(largest)
    for feedback in ("returns", "both"):
        assert in_step_units(model, ds, feedback) == (model, {})
    # an architecture that cannot be scaled is left as it is, and the record says why
    softplus = init_ensemble(model_config("csc_lstm", "push_switch", ds.state_size, output_activation="softplus"), [0])
    kept, record = in_step_units(softplus, ds, "preferences")
    assert kept is softplus and "cannot be calibrated" in record["step_units"]["skipped"]


def test_what_cannot_be_calibrated_is_refused_in_one_line():
    ds = make_toy_dataset("push_switch", 50, seed=0)
    with pytest.raises(CalibrationError, match="embedding_lstm model cannot be calibrated"):
        fit_calibration(init_ensemble(model_config("embedding_lstm", "push_switch", ds.state_size), [0]), ds)
    model = init_ensemble(model_config("csc_lstm", "push_switch", ds.state_size), [0]).eval()
    one = _labelled_by(model, ds, 2.0, 0.0)
    one.returns[1:] = np.nan
    with pytest.raises(CalibrationError, match="at least 2 return-labelled episodes"):
        fit_calibration(model, one)
    with pytest.raises(CalibrationError, match="orders the labelled episodes against their returns"):
        fit_calibration(model, _labelled_by(model, ds, -2.0, 0.0))


def test_nmrm_calibrate_writes_a_calibrated_copy_and_keeps_the_original(tmp_path):
    ds = make_toy_dataset("push_switch", 100, seed=0)
    model = init_ensemble(model_config("csc_lstm", "push_switch", ds.state_size), [0]).eval()
    Run.of(model, "push_switch", train_config={"feedback": "preferences"}).save(tmp_path / "m")
    original = (tmp_path / "m.pt").read_bytes()
    _labelled_by(model, ds, 4.0, -0.05).save(tmp_path / "labels.npz")
    nmrm = executable("nmrm")
    res = subprocess.run([nmrm, "calibrate", "--checkpoint", str(tmp_path / "m"), "--data", str(tmp_path / "labels.npz"),
                          "--labels", "20", "--out", str(tmp_path / "cal")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "calibrated on 20 return labels" in res.stdout and "4 r -0.05 per step" in res.stdout, res.stdout
    cal, meta = load_checkpoint(tmp_path / "cal")
    assert meta.calibration["gain"] == [pytest.approx(4.0, rel=1e-4)]
    assert meta.train_config == {"feedback": "preferences"}
    assert (tmp_path / "m.pt").read_bytes() == original
    # over itself, or without labels: one line, nothing written
    for args, message in ((["--data", str(tmp_path / "labels.npz"), "--out", str(tmp_path / "m")], "is the checkpoint itself"),
                          (["--out", str(tmp_path / "x")], "give the return labels as --data FILE or --bag BAG"),
                          (["--data", str(tmp_path / "labels.npz"), "--labels", "500", "--out", str(tmp_path / "x")],
                           "the data has 100 return-labelled episodes")):
        res = subprocess.run([nmrm, "calibrate", "--checkpoint", str(tmp_path / "m"), *args], capture_output=True,
                             text=True, timeout=120)
        assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert (tmp_path / "m.pt").read_bytes() == original and not (tmp_path / "x.pt").exists()
