"""Toy datasets and screened trajectory datasets (paper App. C, D.2)."""

import dataclasses

import numpy as np
import pytest

from nmrm_ros.datasets import (TrajectoryDataset, classify, cut_episodes, generate_screened, make_toy_dataset,
                               screen_pool, screening_spec)
from nmrm_ros.oracles import make_oracle
from nmrm_ros.tasks.lunar_lander import SCRIPTED_PLANS, rollout_lunar_lander


def test_toy_bag_sizes_and_labels():
    for name in ("toggle_switch", "push_switch", "dial"):
        ds = make_toy_dataset(name, n_bags=500, seed=1)
        assert len(ds) == 500 and ds.state_size == 2
        assert ds.lengths.min() == 10 and ds.lengths.max() == 20
        relabelled = make_oracle(name).label(ds.states, lengths=ds.lengths)
        np.testing.assert_array_equal(relabelled.returns, ds.returns)  # labels match the states
        pad = np.arange(20)[None] >= ds.lengths[:, None]
        assert np.all(ds.states[pad] == 0) and np.all(ds.rewards[pad] == 0)


def test_push_switch_semantics():
    # presses at t = 1 and t = 3: the switch is on for t = 1, 2 only
    states = np.array([[[0, 1], [1, 2], [0, 4], [1, 8], [0, 16]]], np.float32)
    labels = make_oracle("push_switch").label(states)
    assert labels.rewards[0].tolist() == [0, 2, 4, 0, 0]
    assert labels.hidden[0, :, 0].tolist() == [0, 1, 1, 0, 0]


def test_toggle_and_dial_semantics():
    toggle = make_oracle("toggle_switch").label(np.array([[[1, 0.5], [0, 0.7], [1, 0.25]]], np.float32))
    assert toggle.returns[0] == 0.75
    dial = make_oracle("dial").label(np.array([[[0.5, 2.0], [-0.25, 4.0], [0.0, 1.0]]], np.float32))
    # d = 0.5, 0.25, 0.25 -> rewards 1.0, 1.0, 0.25
    assert dial.rewards[0].tolist() == [1.0, 1.0, 0.25]


def test_toy_same_seed_same_dataset():
    a, b = make_toy_dataset("dial", 100, seed=3), make_toy_dataset("dial", 100, seed=3)
    assert a.states.tobytes() == b.states.tobytes() and a.returns.tobytes() == b.returns.tobytes()
    with pytest.raises(ValueError, match="unknown toy"):
        make_toy_dataset("slider")


def _class_limits_respected(ds, key_fourth_class=False):
    spec = screening_spec(ds.task, key_fourth_class)
    classes, counts = np.unique(ds.classes, return_counts=True)
    for c, k in zip(classes.tolist(), counts.tolist()):
        p = spec.default if spec.limits is None else spec.limits.get(c, spec.default)
        # the paper's rule: a trajectory is kept only while its class holds fewer than p * N
        assert k - 1 < max(p * len(ds), 1), (ds.task, c, k)


@pytest.mark.parametrize("task,n", [("timer", 1000), ("moving", 400), ("key", 400),
                                    ("charger", 1000)])
def test_screened_dataset_limits_and_labels(task, n):
    ds = generate_screened(task, n, seed=5, batch=20000)
    assert len(ds) == n and ds.states.shape == (n, 100, 2)
    _class_limits_respected(ds)
    # the stored classes and labels are those of the stored trajectories
    labels = make_oracle(task).label(ds.states, ds.actions)
    np.testing.assert_array_equal(labels.returns, ds.returns)
    np.testing.assert_array_equal(classify(task, ds.states, labels), ds.classes)
    assert ds.meta["draws"] >= n and ds.meta["seed"] == 5


def test_screening_same_seed_same_dataset():
    a = generate_screened("key", 300, seed=11, batch=5000)
    b = generate_screened("key", 300, seed=11, batch=5000)
    c = generate_screened("key", 300, seed=12, batch=5000)
    assert a.states.tobytes() == b.states.tobytes()
    assert a.actions.tobytes() == b.actions.tobytes()
    assert a.states.tobytes() != c.states.tobytes()


def test_small_targets():
    for n in (1, 3, 165):  # ceil(p * n) per class always adds up to at least n
        assert len(generate_screened("key", n, seed=0)) == n


def test_key_fourth_class():
    ds = generate_screened("key", 500, seed=2, key_fourth_class=True)
    assert set(np.unique(ds.classes).tolist()) == {0, 1, 2, 3}
    _class_limits_respected(ds, key_fourth_class=True)
    # class 3: treasure visited but never with the key, so its return is 0
    assert np.all(ds.returns[ds.classes == 3] == 0)
    assert np.all(ds.returns[ds.classes == 2] > 0)


def test_lunar_lander_screening_tops_up_a_short_pool():
    """A pool whose classes' limits keep fewer than asked is topped up by further pools (seeded),
    and a dataset that cannot be filled is a one-line error, not a short dataset."""
    from nmrm_ros.datasets.screening import screen_lunar_lander

    ds = screen_lunar_lander(pool_size=15, seed=0, n_target=10)
    assert len(ds) == 10 and ds.meta["pools"] == 2  # one pool of 15 keeps fewer than 10 (class limit 2)
    _class_limits_respected(ds)
    assert ds.meta["plans"] == SCRIPTED_PLANS  # which plan distribution made it (bench caches check it)
    again = screen_lunar_lander(pool_size=15, seed=0, n_target=10)
    np.testing.assert_array_equal(again.states, ds.states)
    with pytest.raises(ValueError, match=r"only .* episodes kept from 1 pool\(s\)"):
        screen_lunar_lander(pool_size=5, seed=0, n_target=10, max_pools=1)


def test_lunar_lander_pool_screening():
    pool = rollout_lunar_lander(40, seed=0)
    ds = screen_pool("lunar_lander", pool, n_target=20)
    # seed 0 (plans version 3): classes 0, 9, 11, 12, 15, 17 kept 4, 4, 4, 2, 3, 3 (the limit is ceil(0.2 * 20) = 4)
    assert len(ds) == 20 and ds.states.shape[1:] == (500, 8)
    assert np.unique(ds.classes, return_counts=True)[1].tolist() == [4, 4, 4, 2, 3, 3]
    _class_limits_respected(ds)
    assert np.all(ds.returns >= 0)


def test_scripted_lander_lands_on_either_side_of_the_pad_edge():
    """The scripted plans cover the oracle's pad edge (|x| = 0.2) from both sides: a landing
    target on the centre counts steps on the pad, one far out counts none (issue 31: agents found
    the edge that version-1 data, all landed on the centre, never showed the model)."""
    from nmrm_ros.oracles import make_oracle
    from nmrm_ros.tasks.lunar_lander import RewardlessLunarLander, ScriptedLanderController, run_episode

    env, oracle = RewardlessLunarLander(episode_length=300), make_oracle("lunar_lander")
    pad_steps = {}
    for land_x in (0.0, 0.6):
        controller = ScriptedLanderController(np.random.default_rng(0))
        controller.set_plan(wait=60, land=True, noise=0.0, land_x=land_x)
        states, _, _ = run_episode(env, controller, seed=3, steps=299)
        ground = (states[:, 6] == 1) & (states[:, 7] == 1)
        assert ground.sum() >= 50, f"land_x {land_x}: never came to rest"
        pad_steps[land_x] = oracle.label(states[None]).hidden[0].max()
    env.close()
    assert pad_steps == {0.0: 50, 0.6: 0}


def test_scripted_lander_lands_again_after_the_pad_phase():
    """Plans version 3: some take-offs end on the ground again and stay there, so the data show
    the model that contact after the pad phase earns only the shaping term (issue 31: an agent on
    a model of version-2 data hopped after its 50 pad steps, sat down again and was paid ~1.5 a
    step for it, where the oracle pays ~0.1)."""
    from nmrm_ros.oracles import make_oracle
    from nmrm_ros.tasks.lunar_lander import RewardlessLunarLander, ScriptedLanderController, run_episode

    env, oracle = RewardlessLunarLander(), make_oracle("lunar_lander")
    controller = ScriptedLanderController(np.random.default_rng(0))
    controller.set_plan(wait=50, land=True, noise=0.0, reland_after=5, reland_x=0.0)
    states, _, _ = run_episode(env, controller, seed=0, steps=499)
    env.close()
    labels = oracle.label(states[None])
    tail = slice(-100, None)
    assert labels.hidden[0].max() == 50 and controller.phase == "down"
    assert np.all(states[tail, 6] == 1) and np.all(states[tail, 7] == 1)
    assert np.all(labels.rewards[0][tail] <= 0.2)      # shaping only: no pad, no-contact or hover term
    drawn = []
    for seed in range(200):
        c = ScriptedLanderController(np.random.default_rng(seed))
        drawn.append(c.reland_after > 0)
    assert 0.2 < np.mean(drawn) < 0.4                   # RELAND_FRACTION of the plans (0.3)


def test_dataset_save_load_round_trip(tmp_path):
    ds = generate_screened("moving", 200, seed=1)
    back = TrajectoryDataset.load(ds.save(tmp_path / "moving.npz"))
    assert back.task == "moving" and back.meta == ds.meta
    for k in ("states", "actions", "returns", "rewards", "hidden", "lengths", "classes", "final_states"):
        np.testing.assert_array_equal(getattr(back, k), getattr(ds, k))


def test_deduplicated_drops_exact_repeats_only():
    """The dedup rule: same states (final observation included) and same label = same episode."""
    from nmrm_ros.datasets import generate_screened

    ds = generate_screened("key", 30, seed=1)
    twice = ds.subset(np.r_[np.arange(30), [3, 7, 7]])
    twice.meta["episodes"] = list(range(33))
    relabelled = twice.subset(np.arange(33))
    relabelled.returns = relabelled.returns.copy()
    relabelled.returns[32] += 1.0                     # same states, another label: kept
    out, dropped = twice.deduplicated()
    assert dropped == 3 and len(out) == 30
    np.testing.assert_array_equal(out.states, ds.states)
    assert out.meta["episodes"] == list(range(30))
    out2, dropped2 = relabelled.deduplicated()
    assert dropped2 == 2 and len(out2) == 31
    assert ds.deduplicated() == (ds, 0)


def test_save_is_atomic_and_appends_npz_like_numpy(tmp_path):
    """save() writes a temporary file and renames it: no temporary is left, an existing file is
    replaced whole, and a name without ".npz" gets it (the returned path is the file written)."""
    ds = generate_screened("key", 5, seed=1)
    other = generate_screened("key", 7, seed=2)
    path = other.save(tmp_path / "key.npz")
    assert ds.save(path) == path and len(TrajectoryDataset.load(path)) == 5
    bare = ds.save(tmp_path / "bare")
    assert bare == tmp_path / "bare.npz" and len(TrajectoryDataset.load(bare)) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare.npz", "key.npz"]


def test_cut_episodes_label_each_prefix_with_what_it_earned():
    ds = generate_screened("timer", 200, seed=0)
    cut = cut_episodes(ds, 0.5, seed=3)
    shorter = cut.lengths < ds.lengths
    assert shorter.sum() == 100 and (cut.lengths >= 1).all()
    np.testing.assert_array_equal(cut.returns[~shorter], ds.returns[~shorter])  # the others keep their labels
    relabelled = make_oracle("timer").label(cut.states, lengths=cut.lengths)  # a prefix's return, from its states
    np.testing.assert_allclose(cut.returns, relabelled.returns)
    i = np.flatnonzero(shorter)[0]
    np.testing.assert_array_equal(cut.final_states[i], ds.states[i, cut.lengths[i]])
    assert not cut.states[i, cut.lengths[i]:].any() and not cut.rewards[i, cut.lengths[i]:].any()
    np.testing.assert_array_equal(cut_episodes(ds, 0.5, seed=3).lengths, cut.lengths)  # seeded
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        cut_episodes(ds, 1.5, seed=0)
    people = dataclasses.replace(ds, returns=ds.returns + 1.0)  # labels that are not the oracle's
    with pytest.raises(ValueError, match="these labels are not .*--prefix-fraction 0"):
        cut_episodes(people, 0.5, seed=0)
    with pytest.raises(ValueError, match="have none"):
        cut_episodes(dataclasses.replace(ds, meta=dict(ds.meta, oracle_ground_truth=False)), 0.5, seed=0)
