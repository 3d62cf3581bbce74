"""`nmrm explain` and its views: the arrays behind each picture are checked against independent
computations (the online model stepped by hand, the oracle), and the PNGs and index.html exist."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from nmrm_ros.datasets import generate_screened
from nmrm_ros.interpret import explain, model_traces, oracle_traces, probe_states
from nmrm_ros.interpret.embeddings import project
from nmrm_ros.interpret.episode_view import read_episodes
from nmrm_ros.interpret.reward_maps import context_prefixes, grid, learnt_reward_map, oracle_reward_map
from nmrm_ros.mil import OnlineRewardModel, load_checkpoint
from nmrm_ros.bags.episodes import write_dataset_bag


def _online_after(model, prefix):
    online = OnlineRewardModel(model)
    for s in prefix:
        online.step(s)
    return online


def test_reward_map_is_the_online_model_stepped_at_each_grid_point(small_key_checkpoint):
    model, _ = load_checkpoint(small_key_checkpoint)
    (label, prefix), = [(c.label, p) for c, p in context_prefixes("key") if c.label == "key held"]
    n = 7
    learnt = learnt_reward_map(model, prefix, n)
    _, _, points = grid(n)
    expected = np.empty(n * n)
    for i, p in enumerate(points):
        expected[i] = _online_after(model, prefix).step(p)[0]
    np.testing.assert_allclose(learnt.ravel(), expected, atol=1e-5)
    # the oracle's map: reward 1 exactly on the treasure once the key is held, 0 elsewhere
    oracle = oracle_reward_map("key", prefix, n).ravel()
    x, y = points[:, 0], points[:, 1]
    np.testing.assert_array_equal(oracle, ((x >= 0.4) & (x <= 0.6) & (y >= 0.7) & (y <= 0.9)).astype(float))


def test_probe_traces_equal_the_online_models_steps(small_key_checkpoint):
    model, _ = load_checkpoint(small_key_checkpoint)
    for probe, states in probe_states("key"):
        rewards, hidden = model_traces(model, states)
        online = OnlineRewardModel(model)
        steps = [online.step(s) for s in states]
        np.testing.assert_allclose(rewards, [r for r, _ in steps], atol=1e-5, err_msg=probe.name)
        np.testing.assert_allclose(hidden, np.stack([h for _, h in steps]), atol=1e-5, err_msg=probe.name)


@pytest.mark.parametrize("task", ["timer", "moving", "key", "charger"])
def test_probes_are_100_steps_in_the_arena_and_do_what_they_say(task):
    probes = probe_states(task)
    assert probes
    returns = {}
    for probe, states in probes:
        assert states.shape == (100, 2) and states.min() >= 0 and states.max() <= 1
        assert np.all(np.linalg.norm(np.diff(states, axis=0), axis=1) <= 0.1 + 1e-6)
        returns[probe.name] = oracle_traces(task, states)[0].sum()
    if task == "timer":
        assert returns["optimal"] > returns["early"]
    if task == "moving":
        assert returns["optimal left"] > 90 and returns["static"] < 40
    if task == "key":
        assert returns["key first"] > 80 and returns["no key"] == 0
    if task == "charger":
        assert returns["optimal"] > max(returns["under-charged"], returns["over-charged"])


def test_projection_keeps_two_dimensions_and_uses_pca_above_two():
    rng = np.random.default_rng(0)
    two = rng.normal(size=(50, 2))
    points, how, explained = project(two)
    np.testing.assert_array_equal(points, two)
    assert how == "hidden state" and explained is None
    wide = np.c_[rng.normal(size=(200, 1)) * 10, rng.normal(size=(200, 4)) * 0.1]
    points, how, explained = project(wide)
    assert points.shape == (200, 2) and how == "PCA of the 5-D hidden state"
    assert explained[0] > 0.95 and explained.sum() <= 1 + 1e-9
    # the first component is the wide axis (up to sign)
    assert abs(np.corrcoef(points[:, 0], wide[:, 0])[0, 1]) > 0.999


def test_explain_writes_every_view_for_a_bag(small_key_checkpoint, tmp_path):
    ds = generate_screened("key", 12, seed=3)
    bag = write_dataset_bag(ds, tmp_path / "bag")
    episodes = read_episodes(bag)
    assert len(episodes) == 12
    (source, episode), rec = next(iter(episodes.items()))
    assert source == "" and rec.served is None and rec.oracle_recorded
    np.testing.assert_allclose(rec.oracle, ds.rewards[0, :ds.lengths[0]])
    np.testing.assert_allclose(rec.oracle, oracle_traces("key", rec.states)[0])

    out = tmp_path / "views"
    result = subprocess.run([sys.executable, "-m", "nmrm_ros.cli", "explain", "--checkpoint",
                             str(small_key_checkpoint), "--bag", str(bag), "--out", str(out),
                             "--episodes", "2"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    names = sorted(p.name for p in out.glob("*.png"))
    assert names == ["episode_root_0.png", "episode_root_1.png", "hidden_embedding.png",
                     "probe_key_first.png", "probe_no_key.png", "reward_maps.png"]
    for name in names:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    index = (out / "index.html").read_text()
    for name in names:
        assert f"src='{name}'" in index


def test_explain_refuses_a_task_the_checkpoint_was_not_trained_on(small_key_checkpoint, tmp_path):
    with pytest.raises(ValueError, match="trained on 'key', not 'timer'"):
        explain(small_key_checkpoint, tmp_path, task="timer")
    result = subprocess.run([sys.executable, "-m", "nmrm_ros.cli", "explain", "--checkpoint",
                             str(tmp_path / "missing"), "--out", str(tmp_path)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.fixture(scope="module")
def lander_checkpoint(tmp_path_factory):
    """An untrained CSC model of Lunar Lander's size (weight seed 3; min-max-like normalisation):
    the views are checked against its own online steps, so it need not be trained."""
    import torch

    from nmrm_ros.mil import Run
    from nmrm_ros.mil.models import build_model, model_config

    torch.manual_seed(3)
    model = build_model(model_config("csc_lstm", "lunar_lander", 8))
    model.set_normalisation(torch.zeros(8), torch.full((8,), 2.0), return_scale=100.0)
    return Run.of(model.eval(), "lunar_lander").save(tmp_path_factory.mktemp("ll") / "ll_csc")


def test_lander_probes_do_what_they_say():
    from nmrm_ros.oracles.lunar_lander import r_hover

    probes = dict((p.name, s) for p, s in probe_states("lunar_lander"))
    assert list(probes) == ["correct", "no hover", "too short", "never landed"]
    pad = {name: oracle_traces("lunar_lander", s)[1][:, 0] for name, s in probes.items()}
    for name in ("correct", "no hover", "too short"):
        assert probes[name].shape == (500, 8) and pad[name].max() > 0, name
    assert pad["correct"].max() == 50 and pad["no hover"].max() == 50 and 0 < pad["too short"].max() < 50
    hover_after = lambda name: r_hover(probes[name].astype(np.float64))[pad[name] >= 50].sum()  # noqa: E731
    assert hover_after("correct") > 100 and hover_after("no hover") == 0
    # never landed: no pad step, and it ends early by leaving the screen (|x| >= 1)
    assert pad["never landed"].max() == 0 and len(probes["never landed"]) < 500
    assert abs(probes["never landed"][-1, 0]) >= 1.0
    # deterministic: a second rollout is the same path
    np.testing.assert_array_equal(probe_states("lunar_lander")[0][1], probes["correct"])


def test_lander_contexts_mean_what_their_labels_say():
    contexts = context_prefixes("lunar_lander")
    pads = {c.label: oracle_traces("lunar_lander", prefix)[1][-1, 0] for c, prefix in contexts}
    assert pads == {"not landed yet": 0, "25 steps on the pad": 25, "took off after 50 on the pad": 50}
    (_, prefix), = [(c, p) for c, p in contexts if c.label == "took off after 50 on the pad"]
    assert prefix[-1, 6] == 0 and prefix[-1, 7] == 0  # in the air


def test_lander_reward_map_is_the_online_model_and_the_oracle_on_the_grid(lander_checkpoint):
    from nmrm_ros.oracles.lunar_lander import r_hover, r_no_contact, r_shaping

    model, _ = load_checkpoint(lander_checkpoint)
    (_, prefix), = [(c, p) for c, p in context_prefixes("lunar_lander") if c.t == 300]
    n = 5
    learnt = learnt_reward_map(model, prefix, n, "lunar_lander")
    xs, ys, points = grid(n, "lunar_lander")
    assert points.shape == (25, 8) and xs[0] == -1 and xs[-1] == 1 and ys[0] == 0 and ys[-1] == 1.5
    np.testing.assert_array_equal(points[:, 6], (points[:, 1] == 0).astype(np.float32))
    expected = [_online_after(model, prefix).step(p)[0] for p in points]
    np.testing.assert_allclose(learnt.ravel(), expected, atol=1e-5)
    # after 50 steps on the pad the oracle pays no-contact + hover + shaping towards y = 1
    p = points.astype(np.float64)
    np.testing.assert_allclose(oracle_reward_map("lunar_lander", prefix, n).ravel(),
                               r_no_contact(p) + r_hover(p) + r_shaping(p, 1.0))


def test_explain_draws_lander_maps_and_probes(lander_checkpoint, tmp_path):
    figures = explain(lander_checkpoint, tmp_path, n=6, grid_size=9)
    names = sorted(p.name for p in tmp_path.glob("*.png"))
    assert names == ["hidden_embedding.png", "probe_correct.png", "probe_never_landed.png",
                     "probe_no_hover.png", "probe_too_short.png", "reward_maps.png"]
    assert [f.section for f in figures].count("Probe trajectories") == 4
    for name in names:
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
