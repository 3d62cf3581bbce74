"""Preferences as feedback: the Bradley–Terry loss, the simulated teacher's knobs, comparisons kept
aligned by the dataset, metrics that do not depend on scale, and a model trained on comparisons
that ranks held-out pairs."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.datasets.preference_teacher import SimulatedTeacher, draw_pairs, with_preferences
from nmrm_ros.datasets.trajectories import TrajectoryDataset, concatenate
from nmrm_ros.mil.evaluation import comparison_accuracy, preference_accuracy
from nmrm_ros.mil.training import comparison_split, load_train_config, preference_loss


def test_preference_loss_against_hand_computed_values():
    ra = torch.tensor([1.0, 0.0, 2.0, 3.0])
    rb = torch.tensor([0.0, 0.0, 0.0, 1.0])
    p = torch.tensor([1.0, 0.5, 0.0, 0.5])
    # -log s(1); log 2; -log(1 - s(2)) = log(1 + e^2); 0.5 (-log s(2) - log(1 - s(2))) with scale 1
    expected = [math.log(1 + math.exp(-1)), math.log(2), math.log(1 + math.exp(2)),
                0.5 * (math.log(1 + math.exp(-2)) + math.log(1 + math.exp(2)))]
    assert float(preference_loss(ra, rb, p)) == pytest.approx(np.mean(expected), rel=1e-6)
    # scale: differences are divided by it
    assert float(preference_loss(ra * 10, rb * 10, p, scale=10)) == pytest.approx(np.mean(expected), rel=1e-6)
    # batched over members: (K, B) -> (K,)
    assert preference_loss(ra.repeat(3, 1), rb.repeat(3, 1), p.repeat(3, 1)).shape == (3,)


def _ds(n=400, seed=0) -> TrajectoryDataset:
    return make_toy_dataset("toggle_switch", n, seed=seed)


def test_perfect_teacher_is_always_right_and_seeded():
    ds = _ds()
    pairs = draw_pairs(len(ds), 300, seed=1)
    assert len({(min(a, b), max(a, b)) for a, b in pairs}) == 300 and np.all(pairs[:, 0] != pairs[:, 1])
    answers = SimulatedTeacher().answer(ds, pairs, seed=1)
    r = ds.rewards.sum(1)
    a, b, p = answers[:, 0].astype(int), answers[:, 1].astype(int), answers[:, 2]
    assert np.all(p[r[a] > r[b]] == 1) and np.all(p[r[a] < r[b]] == 0)
    np.testing.assert_array_equal(answers, SimulatedTeacher().answer(ds, pairs, seed=1))


def test_teacher_knobs_measured():
    ds = _ds(2000)
    pairs = draw_pairs(len(ds), 6000, seed=2)
    r = ds.rewards.sum(1)
    decided = r[pairs[:, 0]] != r[pairs[:, 1]]
    truth = (r[pairs[:, 0]] > r[pairs[:, 1]]).astype(float)
    wrong = SimulatedTeacher(mistake=0.2).answer(ds, pairs, seed=3)
    rate = np.mean(wrong[decided, 2] != truth[decided])
    assert 0.17 < rate < 0.23, rate  # ~0.2 of 6000 answers flipped
    noisy = SimulatedTeacher(beta=1.0).answer(ds, pairs, seed=3)  # sigmoid(beta * diff)
    diff = r[pairs[:, 0]] - r[pairs[:, 1]]
    chance = 1 / (1 + np.exp(-diff))
    assert abs(noisy[:, 2].mean() - chance.mean()) < 0.02
    equal = SimulatedTeacher(equal=np.inf).answer(ds, pairs, seed=3)
    assert np.all(equal[:, 2] == 0.5)
    skip = SimulatedTeacher(skip=np.inf).answer(ds, pairs, seed=3)
    assert len(skip) == 0
    with pytest.raises(ValueError, match="teacher setting mistake"):
        SimulatedTeacher(mistake=1.5).check()
    with pytest.raises(ValueError, match="gamma"):
        SimulatedTeacher(gamma=0).check()


def test_myopic_teacher_weighs_late_steps_more():
    ds = _ds(50)
    judged = SimulatedTeacher(gamma=0.5).judged_returns(ds)
    i = 0
    n = int(ds.lengths[i])
    expected = sum(ds.rewards[i, t] * 0.5 ** (n - 1 - t) for t in range(n))
    assert judged[i] == pytest.approx(expected)


def test_subset_concatenate_and_file_keep_comparisons_aligned(tmp_path):
    ds = with_preferences(_ds(100), 200, SimulatedTeacher(), seed=0)
    idx = np.arange(0, 100, 2)[::-1]
    sub = ds.subset(idx)
    for a, b, p in sub.preferences:
        row = np.flatnonzero((ds.preferences[:, 0] == idx[int(a)]) & (ds.preferences[:, 1] == idx[int(b)]))
        assert len(row) == 1 and ds.preferences[row[0], 2] == p
    both = concatenate([sub, ds])
    assert len(both.preferences) == len(sub.preferences) + len(ds.preferences)
    np.testing.assert_array_equal(both.preferences[len(sub.preferences):, :2], ds.preferences[:, :2] + len(sub))
    back = TrajectoryDataset.load(ds.save(tmp_path / "d.npz"))
    np.testing.assert_array_equal(back.preferences, ds.preferences)
    assert back.meta["preferences"]["teacher"]["beta"] == "inf"


def test_comparison_split_never_uses_a_test_trajectory():
    prefs = np.column_stack([draw_pairs(100, 400, 0), np.ones(400)]).astype(float)
    train, val = np.arange(80), np.arange(80, 90)
    tr, va = comparison_split(prefs, train, val, seed=0)
    used = prefs[np.concatenate([tr, va]), :2]
    assert used.max() < 90 and not set(tr) & set(va)
    assert len(va) == pytest.approx(len(tr) / 8, abs=2)


def test_metrics_do_not_depend_on_scale_or_offset():
    labels = np.array([0.0, 1.0, 2.0, 2.0, 5.0])
    acc, pairs = preference_accuracy(labels * 7 - 3, labels)
    assert (acc, pairs) == (1.0, 9)
    acc, _ = preference_accuracy(-labels, labels)
    assert acc == 0.0
    prefs = np.array([[0, 1, 0.0], [4, 2, 1.0], [2, 3, 0.5]])
    assert comparison_accuracy(labels, prefs) == (1.0, 2)


def test_a_model_trained_on_comparisons_ranks_held_out_pairs():
    """Push switch (the reward depends on whether the switch was pushed earlier) from 1500
    comparisons of a perfect teacher: held-out preference accuracy well above chance, and above a
    Markovian model trained on the same comparisons (measured: 0.94 vs 0.66)."""
    from nmrm_ros.mil.pipeline import fit

    ds = with_preferences(make_toy_dataset("push_switch", 1000, seed=0), 1500, SimulatedTeacher(), seed=0)
    held = make_toy_dataset("push_switch", 300, seed=7)
    from nmrm_ros.mil import evaluate
    scores = {}
    for arch in ("csc_lstm", "instance_nn"):
        cfg = load_train_config("push_switch", max_epochs=40, feedback="preferences")
        run = fit(ds, arch, cfg, progress=False)
        scores[arch] = evaluate(run.model, held)
        # served in units of its largest step on its training episodes (comparisons leave the scale free)
        assert run.meta.metrics["step_units"]["largest_step_reward"] > 0
    assert scores["csc_lstm"]["preference_accuracy"] > 0.85, scores
    assert scores["csc_lstm"]["reward_correlation"] > 0.8, scores
    assert scores["csc_lstm"]["preference_accuracy"] > scores["instance_nn"]["preference_accuracy"] + 0.15, scores


def test_the_l1_prior_is_not_used_on_comparisons_alone():
    """Comparisons leave the rewards' scale free: the L1 prior would only shrink it (Timer from
    comparisons fell to chance with it), so feedback preferences trains the same without it."""
    from nmrm_ros.mil.pipeline import fit

    ds = with_preferences(make_toy_dataset("push_switch", 100, seed=0), 150, SimulatedTeacher(), seed=0)
    runs = [fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=2, feedback="preferences",
                                                                 reward_l1=l1), progress=False)
            for l1 in (0.0, 0.5)]
    for a, b in zip(runs[0].model.parameters(), runs[1].model.parameters()):
        assert torch.equal(a, b)


def test_feedback_errors_are_one_line():
    from nmrm_ros.mil.pipeline import fit

    ds = _ds(100)
    cfg = load_train_config("toggle_switch", max_epochs=1, feedback="preferences")
    with pytest.raises(ValueError, match="needs preferences"):
        fit(ds, "csc_lstm", cfg, progress=False)
    unlabelled = TrajectoryDataset(ds.task, ds.states, ds.lengths, np.full(len(ds), np.nan), ds.rewards,
                                   ds.hidden, meta=ds.meta)
    with pytest.raises(ValueError, match="no return label"):
        fit(unlabelled, "csc_lstm", load_train_config("toggle_switch", max_epochs=1),
                           progress=False)
    with pytest.raises(ValueError, match="feedback must be"):
        load_train_config("toggle_switch", feedback="stars")


def test_bag_round_trip_of_comparisons_without_returns(tmp_path):
    """A preference-only bag: every compared episode comes back with return NaN and its
    comparisons, joined by episode number; episodes nobody compared are skipped as unlabelled."""
    from nmrm_ros.bags import write_dataset_bag
    from nmrm_ros.bags.episodes import load_bag_dataset
    from nmrm_ros.bags.reader import iter_decoded
    from nmrm_ros.datasets import generate_screened

    ds = with_preferences(generate_screened("timer", 40, seed=0), 50, SimulatedTeacher(), seed=0)
    write_dataset_bag(ds, tmp_path / "bag", returns=False, preference_labeller="oracle/timer")
    types = {t for _, t, _, _ in iter_decoded(tmp_path / "bag")}
    assert "nmrm_msgs/msg/TrajectoryReturn" not in types and "nmrm_msgs/msg/TrajectoryPreference" in types
    back, report = load_bag_dataset([tmp_path / "bag"])
    assert report.comparisons_seen == report.comparisons_used == 50
    assert np.isnan(back.returns).all()
    compared = set(ds.preferences[:, :2].astype(int).ravel())
    assert sorted(back.meta["episodes"]) == sorted(compared)
    episode = np.asarray(back.meta["episodes"])
    got = {(episode[int(a)], episode[int(b)], p) for a, b, p in back.preferences}
    assert got == {(int(a), int(b), p) for a, b, p in ds.preferences}


def test_labeller_oracle_publishes_comparisons_over_real_topics(ros_domain):
    """A real labeller_oracle with feedback both: a return label per episode and one comparison per
    episode after the first, each ordered as the returns are (a perfect teacher)."""
    import signal

    from rclpy.duration import Duration

    from nmrm_ros.testing.graph import Capture, finish, start
    from nmrm_msgs.msg import EnvObservation
    from nmrm_ros.oracles import make_oracle
    from nmrm_ros.ros.topics import OBSERVATION

    capture = Capture()
    try:
        labeller = start("labeller_oracle", task="key", feedback="both", pair_pool=5, noise_seed=2)
        pub = capture.publisher(EnvObservation, OBSERVATION)
        capture.wait_for_publishers({"label": 1, "preference": 1})
        assert capture.spin_until(lambda: pub.get_subscription_count() >= 1, 30)
        rng = np.random.default_rng(0)
        oracle = make_oracle("key")
        truth = []
        for e in range(12):
            states = np.clip(np.cumsum(rng.normal(0, 0.08, (101, 2)), axis=0) + [0.5, 0.2], 0, 1)
            states[30:30 + 3 * e] = [0.5, 0.8]
            truth.append(oracle.label(states[None, :100]).returns[0])
            for t, s in enumerate(states.astype(np.float32)):
                pub.publish(EnvObservation(task="key", episode=e, step=t, state=s.tolist(),
                                           truncated=(t == 100)))
        assert pub.wait_for_all_acked(Duration(seconds=30))
        assert capture.spin_until(lambda: len(capture.msgs["preference"]) >= 11, 30)
        labeller.send_signal(signal.SIGINT)
        code, out = finish(labeller)
    finally:
        capture.close()
    assert len(capture.msgs["label"]) == 12
    prefs = capture.msgs["preference"]
    assert len(prefs) == 11 and all(m.labeller == "oracle/key" and m.length_a == m.length_b == 100 for m in prefs)
    for m in prefs:
        want = np.sign(truth[m.episode_a] - truth[m.episode_b])
        assert m.preference == (0 if want == 0 else want) or (want == 0 and m.preference == -1), m
    assert code == 0 and "11 comparison(s)" in out, out


def test_centred_correlation_ignores_a_function_of_time_added_to_every_bag():
    from nmrm_ros.mil.evaluation import centred, correlation

    rng = np.random.default_rng(0)
    true = rng.normal(size=(50, 10))
    step = np.tile(np.arange(10), 50)
    shifted = true + np.linspace(-30, 30, 10)[None, :]  # g(t): invisible to comparisons of equal-length bags
    assert correlation(shifted.ravel(), true.ravel()) < 0.2
    assert correlation(centred(shifted.ravel(), step), centred(true.ravel(), step)) == pytest.approx(1.0)


def test_team_comparisons_are_reported_and_recorded_as_provenance(tmp_path):
    """Two people and the oracle compare in labels bags (LabelStore, as the page writes them):
    `nmrm labels report` counts each labeller's comparisons, their agreement with gold and with
    each other; a dataset from the bags records every comparison it uses."""
    import subprocess

    from nmrm_ros.testing.graph import executable
    from nmrm_ros.bags import write_dataset_bag
    from nmrm_ros.bags.episodes import load_bag_dataset
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.labelling import LabelStore

    ds = generate_screened("key", 12, seed=0)
    write_dataset_bag(ds, tmp_path / "rec", include_oracle=False)
    n = int(ds.lengths[0])
    answers = {"person/alice": [(0, 1, 1.0), (2, 3, 0.0), (4, 5, 1.0)],
               "person/bob": [(1, 0, 0.0), (2, 3, 1.0)],          # (1, 0, 0) is alice's (0, 1, 1) turned round
               "gold/oracle": [(0, 1, 1.0), (4, 5, 0.0)]}
    for who, rows in answers.items():
        store = LabelStore(tmp_path / "labels", who)
        for t, (a, b, p) in enumerate(rows):
            store.append_comparison("key", a, n, b, n, p, stamp_ns=10**9 * (t + 1))
        store.close()
    bags = sorted(str(p) for p in (tmp_path / "labels").iterdir())
    res = subprocess.run([executable("nmrm"), "labels", "report", *sum((["--bag", b] for b in bags), [])],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "person/alice                        3  2, 50%" in out, out   # (0,1) as gold, (4,5) not
    assert "person/bob                          2  1, 100%" in out, out
    assert "agreement: 2 pair(s) compared by two or more people; 50% of their answers the same" in out, out
    data, report = load_bag_dataset([tmp_path / "rec", *bags], labeller="person/alice")
    assert report.comparisons_used == 3 and len(data.meta["comparisons"]) == 3
    assert {(r["a"], r["b"], r["p"], r["labeller"]) for r in data.meta["comparisons"]} == \
        {(a, b, p, "person/alice") for a, b, p in answers["person/alice"]}


def test_deduplicating_compared_only_episodes_keeps_their_comparisons():
    """Two copies of an episode that was only compared (return NaN) are one episode, and a
    comparison that named the dropped copy names the kept one (it was dropped with it before)."""
    from dataclasses import replace

    ds = make_toy_dataset("toggle_switch", 3, seed=0)
    ds = replace(ds, returns=np.full(3, np.nan), preferences=None)
    twice = concatenate([ds, ds])  # episodes 3, 4, 5 repeat 0, 1, 2
    twice = replace(twice, preferences=np.array([[0.0, 1.0, 1.0], [4.0, 2.0, 0.0], [3.0, 0.0, 0.5]]))
    out, dropped = twice.deduplicated()
    assert dropped == 3 and len(out) == 3
    # 0 vs 1 stays; 4 vs 2 is 1 vs 2; 3 vs 0 is an episode against itself: no comparison
    assert out.preferences.tolist() == [[0.0, 1.0, 1.0], [1.0, 2.0, 0.0]]
