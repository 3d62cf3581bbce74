"""The reward-model <-> agent loop: a model swapped under a running agent, its replay buffer
relabelled with the new model, and `nmrm loop` end to end (tiny budgets: only the wiring matters)."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from nmrm_ros.testing.graph import executable
from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import OnlineRewardModel, load_checkpoint, load_train_config
from nmrm_ros.mil.online import batched_reference
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.rl import EpisodeSeeds, RewardModelWrapper, load_rl_config, make_algorithm, make_reward_env
from nmrm_ros.datasets import TrajectoryDataset
from nmrm_ros.rl.replay_relabel import adopt_model, catch_up, relabel_replay_buffer
from nmrm_ros.rl.reward_model_loop import last_model_check, last_model_verdict, round_pairs
from nmrm_ros.tasks import make_env, task_info

D = task_info("key").state_size  # the raw state's part of an observation


@pytest.fixture(scope="module")
def two_models(tmp_path_factory):
    """Two different Key CSC models (weight seeds 0 and 1, 2 epochs): the old one and the new one."""
    ds = generate_screened("key", 200, seed=0)
    out = tmp_path_factory.mktemp("models")
    return [fit(ds, "csc_lstm", load_train_config("key", max_epochs=2, seed=s),
                               out=out / f"key_{s}", progress=False).checkpoint for s in (0, 1)]


def test_a_swapped_model_serves_the_episode_in_progress_as_if_it_had_served_it_from_the_start(two_models):
    old, new = two_models
    actions = np.random.default_rng(3).integers(0, 5, 30)
    swapped = RewardModelWrapper(EpisodeSeeds(make_env("key"), 5), old, task="key")
    fresh = RewardModelWrapper(EpisodeSeeds(make_env("key"), 5), new, task="key")
    swapped.reset(seed=5)
    fresh.reset(seed=5)
    for a in actions[:20]:
        swapped.step(a)
        obs_fresh = fresh.step(a)[0]
    obs = swapped.swap_model(new)
    np.testing.assert_allclose(obs, obs_fresh, rtol=1e-6, atol=1e-6)
    for a in actions[20:]:
        o1, r1, *_ = swapped.step(a)
        o2, r2, *_ = fresh.step(a)
        np.testing.assert_allclose(o1, o2, rtol=1e-6, atol=1e-6)
        assert r1 == pytest.approx(r2)
    assert swapped._returns[0] == pytest.approx(fresh._returns[0])  # noqa: SLF001


def test_a_swap_refuses_a_model_of_another_served_size(two_models, tmp_path):
    ds = generate_screened("key", 50, seed=0)
    bigger = fit(ds, "csc_lstm", load_train_config("key", max_epochs=1, hidden_size=4),
                                out=tmp_path / "h4", progress=False).checkpoint
    env = RewardModelWrapper(EpisodeSeeds(make_env("key"), 5), two_models[0], task="key")
    env.reset(seed=5)
    with pytest.raises(ValueError, match="serves 8 values for states of size 2; the agent observes 4 for 2"):
        env.swap_model(bigger)


@pytest.mark.parametrize("buffer_size", [10_000, 250])  # 250: the buffer wraps round mid-episode
def test_the_replay_buffer_is_relabelled_with_the_new_model(two_models, buffer_size):
    old, new = two_models
    env = make_reward_env("key", "model", old, seed=0)
    cfg = load_rl_config("dqn", learning_starts=10_000, buffer_size=buffer_size)
    agent = make_algorithm(env, "dqn", cfg, 100, seed=0)
    agent.learn(total_timesteps=350)  # three and a half episodes, no gradient step
    buf = agent.replay_buffer
    model, _ = load_checkpoint(new)
    n = relabel_replay_buffer(buf, OnlineRewardModel(model, served="h_tanh_c"), D)
    assert n == min(350, buffer_size)
    size = buf.buffer_size if buf.full else buf.pos
    order = (np.arange(size) + buf.pos) % size if buf.full else np.arange(size)
    ends = [i for i, idx in enumerate(order) if buf.dones[idx, 0]]
    starts = [0] + [e + 1 for e in ends]
    for start, end in zip(starts, ends + [len(order) - 1]):
        idx = order[start:end + 1]
        states = np.concatenate([buf.observations[idx, 0, :D], buf.next_observations[idx[-1:], 0, :D]])
        rewards, served = batched_reference(model, states, "h_tanh_c")
        np.testing.assert_allclose(buf.rewards[idx, 0], rewards[:-1], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(buf.observations[idx, 0, D:], served[:-1], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(buf.next_observations[idx, 0, D:], served[1:], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("algo", ["dqn", "sac"])
def test_catch_up_refits_the_agent_on_its_buffer_without_acting(algo):
    """After a model change the agent takes gradient steps on the relabelled buffer, its target
    networks following, before it acts again: no env step, the exploration schedule unmoved, at
    most one step per stored transition; none before it has learning_starts transitions."""
    import torch

    cfg = load_rl_config(algo, task="key", learning_starts=10_000)
    env = make_reward_env("key", "oracle", seed=0, continuous=algo == "sac")
    agent = make_algorithm(env, algo, cfg, 100, seed=0)
    agent.learn(total_timesteps=300)  # no gradient step yet: learning_starts not reached
    assert agent._n_updates == 0  # noqa: SLF001
    assert catch_up(agent, 50) == 0  # fewer transitions than learning_starts
    agent.learning_starts = 100
    target = agent.q_net_target if algo == "dqn" else agent.critic_target
    before = [p.detach().clone() for p in target.parameters()]
    steps, eps = agent.num_timesteps, getattr(agent, "exploration_rate", None)
    assert catch_up(agent, 50) == 50
    assert agent._n_updates == 50 and agent.num_timesteps == steps  # noqa: SLF001
    assert getattr(agent, "exploration_rate", None) == eps
    assert any(not torch.equal(a, b) for a, b in zip(before, target.parameters()))
    assert catch_up(agent, 10_000) == 300  # no more steps than transitions stored
    assert catch_up(agent, 0) == 0


def test_adopting_a_new_model_relabels_then_catches_up(two_models):
    old, new = two_models
    agent = make_algorithm(make_reward_env("key", "model", old, seed=0), "dqn",
                           load_rl_config("dqn", learning_starts=100), 100, seed=0)
    agent.learn(total_timesteps=200)
    updates = agent._n_updates  # noqa: SLF001
    model, _ = load_checkpoint(new)
    assert adopt_model(agent, OnlineRewardModel(model, served="h_tanh_c"), D, 150) == (200, 150)
    assert agent._n_updates == updates + 150  # noqa: SLF001


def test_nmrm_loop_runs_rounds_and_writes_what_it_says(tmp_path):
    out = tmp_path / "loop"
    res = subprocess.run([executable("nmrm"), "loop", "--task", "key", "--rounds", "3", "--labels-per-round", "20",
                          "--episodes", "6", "--members", "2", "--max-epochs", "2", "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "round 2: 20 labels from agent episodes" in res.stdout
    assert "agent: 400 stored transitions relabelled with model 2, 400 catch-up gradient steps" in res.stdout
    summary = json.loads((out / "loop.json").read_text())
    assert [r["total_labels"] for r in summary["rounds"]] == [20, 40, 60]
    assert [(r["first_episode"], r["last_episode"]) for r in summary["rounds"]] == [(0, 2), (2, 4), (4, 6)]
    assert summary["rounds"][1]["training"]["start"].startswith("warm-started from")
    assert isinstance(summary["collapsed"], bool) and summary["collapse"]
    assert "last model (model 2) on the agent's last 2 episodes: paid" in res.stdout
    assert isinstance(summary["last_model_agrees"], bool) and summary["last_model_check"]
    for name in ("labels.npz", "model_0.pt", "model_2.pt", "agent/policy.zip", "agent/curve.csv"):
        assert (out / name).stat().st_size > 0
    assert len((out / "agent/curve.csv").read_text().splitlines()) == 7


def test_the_loop_says_when_its_last_model_still_overpays_the_agent():
    """The delivery robot's loop of seed 0 (runs/your_own_task, 2026-12-07): model 3 paid the
    agent's last 50 episodes 172.6 where the oracle paid 138.7; the same loop's seed 1, 167.3 / 161.4."""
    rng = np.random.default_rng(0)
    first = rng.uniform(0, 30, 500)  # round 0's random episodes: scale max(15, 8.7)
    judged = np.full(100, 138.7)
    hacked = last_model_check(judged + 33.9, judged, 3, 95.8, first)  # RMSE 9.8: tolerance 29.4
    assert not hacked.passed and hacked.episodes == 50
    assert "gap +33.90, tolerance 29.36): FAIL: the model is still wrong where the agent goes" in \
        last_model_verdict(hacked, 4)
    assert "(--rounds 5)" in last_model_verdict(hacked, 4)
    fine = last_model_check(judged + 5.9, judged, 3, 39.8, first)
    assert fine.passed and last_model_verdict(fine).endswith("PASS")
    assert last_model_check(judged - 33.9, judged, 3, 95.8, first).passed is False  # underpaying is wrong too
    small = last_model_check(np.full(10, 1.04), np.ones(10), 0, 0.0, np.zeros(5))
    assert small.tolerance == pytest.approx(0.05) and small.passed  # 5% of the oracle's scale


def test_a_rounds_comparisons_each_pair_a_new_episode_with_another():
    rng = np.random.default_rng(0)
    first = round_pairs(0, 30, 50, rng)
    assert first.shape == (50, 2) and (first[:, 0] != first[:, 1]).all() and first.max() < 30
    pairs = round_pairs(30, 20, 50, rng)
    new = pairs >= 30
    assert pairs.shape == (50, 2) and (pairs[:, 0] != pairs[:, 1]).all() and pairs.max() < 50
    assert new.any(axis=1).all()  # every comparison shows one of the round's new episodes
    assert set(range(30, 50)) <= set(pairs.ravel().tolist())  # each new episode is compared at least once
    assert (~new).any() and new[:, 0].any() and new[:, 1].any()  # old episodes too, shown on either side


def test_nmrm_loop_learns_from_a_teachers_comparisons(tmp_path):
    out = tmp_path / "loop"
    res = subprocess.run([executable("nmrm"), "loop", "--task", "key", "--rounds", "2", "--labels-per-round", "20",
                          "--episodes", "4", "--members", "2", "--max-epochs", "2", "--feedback", "preferences",
                          "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "round 1: 20 comparisons of 20 episodes from agent episodes" in res.stdout
    assert "val pref. acc." in res.stdout
    summary = json.loads((out / "loop.json").read_text())
    assert [r["total_labels"] for r in summary["rounds"]] == [20, 40]
    assert [r["training"]["feedback"] for r in summary["rounds"]] == ["preferences"] * 2
    assert summary["teacher"]["beta"] == "inf"
    assert summary["last_model_agrees"] is None and "last model" not in res.stdout  # its own units
    ds = TrajectoryDataset.load(out / "labels.npz")
    assert len(ds) == 40 and ds.preferences.shape == (40, 3)
    assert (ds.preferences[:20, :2] < 20).all() and (ds.preferences[20:, :2] >= 20).any(axis=1).all()
    better = np.where(ds.preferences[:, 2] == 1, ds.preferences[:, 0], ds.preferences[:, 1]).astype(int)
    worse = np.where(ds.preferences[:, 2] == 1, ds.preferences[:, 1], ds.preferences[:, 0]).astype(int)
    decided = ds.preferences[:, 2] != 0.5
    assert (ds.returns[better] >= ds.returns[worse])[decided].all()  # a perfect teacher


@pytest.mark.parametrize("args,message", [
    ("--feedback votes", "feedback must be one of returns, preferences, both"),
    ("--feedback preferences --beta 0", "beta"),
    ("--rounds 0", "--rounds"),
    ("--labels-per-round 5", "--labels-per-round"),
    ("--rounds 5 --episodes 3", "3 agent episodes cannot be split over 5 rounds"),
    ("--task nowhere", "unknown task 'nowhere'"),
])
def test_nmrm_loop_refuses_nonsense_in_one_line(tmp_path, args, message):
    argv = ["loop", "--task", "key", "--out", str(tmp_path / "x")] + args.split()
    res = subprocess.run([executable("nmrm"), *argv], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "x").exists()
