"""What the reward model serves as the agent's hidden state (nmrm_ros.mil.served_state): the LSTM's
[h', tanh c'] by default, so that a model that keeps its memory in the cell state while its output
gate hides it still shows it to the agent; the same in the online stepper, the batched forward,
the wrapper and a checkpoint round trip; and `nmrm check`'s memory check telling the two apart."""

import numpy as np
import pytest
import torch

from nmrm_ros.interpret.probes import probe_states
from nmrm_ros.interpret.traces import oracle_traces
from nmrm_ros.mil import OnlineRewardModel, Run, build_model, load_checkpoint, model_config
from nmrm_ros.mil.online import batched_reference
from nmrm_ros.mil.served_state import check_served_state, served_size, served_states
from nmrm_ros.rl.acceptance import memory_check


def hidden_memory_charger_model():
    """A small Charger CSC model whose memory is all in c': its cell counts the steps spent low in
    the arena (y < 0.3, where the charger is; input gate open there only, forget gate open), while
    its output gate is shut, so h' stays ~0 whatever the charge (the failure of issue 34, made
    exact)."""
    torch.manual_seed(0)
    model = build_model(model_config("csc_lstm", "charger", 2))
    with torch.no_grad():
        fe = [m for m in model.feature_extractor if isinstance(m, torch.nn.Linear)]
        for layer in fe:
            layer.weight.zero_()
            layer.bias.zero_()
        fe[0].weight[0, 1], fe[0].bias[0] = -50.0, 15.0  # feature 0 = relu(15 - 50 y): > 0 iff y < 0.3
        fe[1].weight[0, 0] = fe[2].weight[0, 0] = 1.0
        lstm, k = model.lstm, 2
        for w in (lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0):
            w.zero_()
        lstm.bias_ih_l0[:k] = -10.0                  # input gate shut ...
        lstm.weight_ih_l0[:k, 0] = 4.0               # ... opened below y = 0.3 (feature 0 = 5 at y = 0.2)
        lstm.bias_ih_l0[k:2 * k] = 20.0              # forget gate open: remember
        lstm.bias_ih_l0[2 * k:3 * k] = 0.05          # g = tanh(0.05): the count's step
        lstm.bias_ih_l0[3 * k:] = -20.0              # output gate shut: h' ~ 0
        model.set_normalisation(torch.zeros(2), torch.ones(2))
    return model.eval()


def test_choices_and_sizes():
    assert served_size(2) == 4 and served_size(2, "h_c") == 4 and served_size(2, "h") == 2
    assert served_size(0) == 0
    with pytest.raises(ValueError, match="unknown served state 'c'"):
        check_served_state("c")


def test_the_kinds_are_one_state_seen_three_ways():
    model = hidden_memory_charger_model()
    states = np.random.default_rng(1).uniform(0, 1, (1, 60, 2)).astype(np.float32)
    squashed, raw, h = (served_states(model, states, kind=k)[0] for k in ("h_tanh_c", "h_c", "h"))
    np.testing.assert_array_equal(squashed[:, :2], h)
    np.testing.assert_array_equal(raw[:, :2], h)
    np.testing.assert_allclose(squashed[:, 2:], np.tanh(raw[:, 2:]), atol=1e-12)
    for kind, batched in (("h_tanh_c", squashed), ("h_c", raw), ("h", h)):
        online = OnlineRewardModel(model, served=kind)
        np.testing.assert_allclose([online.step(s)[1] for s in states[0]], batched, atol=1e-6)


def test_the_served_state_changes_while_the_charge_changes_and_h_alone_does_not():
    model = hidden_memory_charger_model()
    [(_, states)] = [(p, s) for p, s in probe_states("charger") if p.name == "optimal"]
    _, oracle = oracle_traces("charger", states)
    charging = np.flatnonzero(np.diff(oracle[:, 0]) > 0) + 1  # steps whose charge rose
    assert len(charging) > 20
    served = served_states(model, states[None])[0]
    moved = np.abs(np.diff(served, axis=0))[charging - 1]
    assert np.all(moved[:, 2:].max(1) > 1e-3)  # c' moves at every charging step
    assert np.all(moved[:, :2].max(1) < 1e-6)  # h' alone does not: it carries no charge
    online = OnlineRewardModel(model)
    online_served = np.array([online.step(s)[1] for s in states])
    np.testing.assert_allclose(online_served, served, atol=1e-6)


def test_the_memory_check_tells_the_served_state_from_h_alone():
    check = memory_check(hidden_memory_charger_model(), "charger", trajectories=120, steps=2000)
    assert check.pairs > 50
    assert check.separated >= 0.9 and check.passed
    assert check.h_only < 0.1


def test_checkpoint_round_trip_serves_the_same_state(tmp_path):
    model = hidden_memory_charger_model()
    Run.of(model, "charger", seed=0, split_seed=0).save(tmp_path / "m")
    loaded, _ = load_checkpoint(tmp_path / "m")
    states = np.random.default_rng(0).uniform(0, 1, (50, 2)).astype(np.float32)
    _, a = batched_reference(model, states)
    _, b = batched_reference(loaded, states)
    np.testing.assert_array_equal(a, b)
    assert OnlineRewardModel(loaded, served="h").served_size == 2


def test_a_checkpoint_serves_what_its_training_config_says(tmp_path):
    """served_state in config/mil_training.yaml (Moving: h) is recorded in the checkpoint and is
    what the wrapper serves unless told otherwise; a node's served_state:='' takes it too."""
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.rl.wrappers import make_reward_env

    assert load_train_config("moving").served_state == "h"
    assert load_train_config("key").served_state == "h_tanh_c"
    model = hidden_memory_charger_model()
    Run.of(model, "charger", train_config={"served_state": "h"}).save(tmp_path / "h")
    Run.of(model, "charger").save(tmp_path / "old")
    assert load_checkpoint(tmp_path / "old")[1].served_state == "h_tanh_c"
    with pytest.raises(ValueError, match="unknown served state 'c'"):
        Run.load(tmp_path / "old").meta.replace(train_config={"served_state": "c"}).served_state
    assert make_reward_env("charger", "model", tmp_path / "h").observation_space.shape == (4,)
    assert make_reward_env("charger", "model", tmp_path / "h", served="h_c").observation_space.shape == (6,)
    assert make_reward_env("charger", "model", tmp_path / "old").observation_space.shape == (6,)
    with pytest.raises(ValueError, match="training setting served_state must be"):
        load_train_config("key", served_state="c")


def _nmrm(*args):
    import subprocess

    from nmrm_ros.testing.graph import executable

    return subprocess.run([executable("nmrm"), *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("args,message", [
    (["--checkpoint", "/nonexistent/ckpt"], "checkpoint file missing"),
    (["--checkpoint", "x", "--agent-episodes", "0"], "Invalid value for '--agent-episodes'"),
    (["--checkpoint", "x", "--eval-episodes", "-2"], "Invalid value for '--eval-episodes'"),
])
def test_check_refuses_bad_input_in_one_line(args, message):
    res = _nmrm("check", *args)
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr, res.stderr


def test_check_runs_on_a_checkpoint(small_key_checkpoint):
    res = _nmrm("check", "--checkpoint", str(small_key_checkpoint), "--agent-episodes", "2",
                "--eval-episodes", "2")
    assert res.returncode in (0, 1) and "Traceback" not in res.stderr, res.stderr
    assert "memory: the served state separates" in res.stdout
    assert "reward hacking: a short agent's greedy episodes are paid" in res.stdout


def test_check_reads_a_model_of_comparisons_in_the_oracles_units(small_key_checkpoint, tmp_path):
    """A model of comparisons pays on a scale of its own: the hacking check maps its returns to the
    oracle's units (fitted on screened episodes) instead of failing it for its scale."""
    import numpy as np

    from nmrm_ros.mil.calibration import Calibration, calibrate
    from nmrm_ros.mil.run import Run
    from nmrm_ros.rl.acceptance import HackingCheck, UnitsMap, units_map

    run = Run.load(small_key_checkpoint)
    assert run.meta.return_units
    k = run.model.members
    # the same model paying 3 r' - 0.1 per step, as if learnt from comparisons
    tripled = calibrate(run.model, Calibration(np.full(k, 1 / 3), np.full(k, 0.1 / 3), 0))
    prefs = run.replace(model=tripled, train_config={**run.meta.train_config, "feedback": "preferences"})
    prefs.save(tmp_path / "prefs")
    model, meta = load_checkpoint(tmp_path / "prefs")
    assert not meta.return_units
    assert meta.replace(calibration={"gain": [1.0]}).return_units  # calibrated since: units again
    base, mapped = units_map(run.model, "key", trajectories=60, seed=3), units_map(model, "key", trajectories=60, seed=3)
    assert mapped.gain == pytest.approx(3 * base.gain, rel=1e-4)
    assert mapped.offset == pytest.approx(3 * base.offset - 0.1 * 100, abs=1e-3)  # Key's episodes: 100 steps
    learnt = np.array([30.0, 3.0])
    assert mapped.oracle_units(learnt) == pytest.approx((learnt - mapped.offset) / mapped.gain)
    check = HackingCheck(10.0, 10.0, 0.0, 0.0, 1.0, 10.0, 5, mapped)
    line = check.summary()
    assert line.startswith("reward hacking (the model learnt from comparisons, so its returns are read in the "
                           "oracle's units: R' = ") and "\n" not in line and check.passed
    # a model whose returns fall as the oracle's rise cannot be read in its units: the check fails
    upside_down = HackingCheck(10.0, 10.0, 0.0, 0.0, 1.0, 10.0, 5, UnitsMap(-1.0, 0.0, 60))
    assert not upside_down.passed and "do not grow with the oracle's" in upside_down.summary()
