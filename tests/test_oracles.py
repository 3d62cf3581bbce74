"""Oracles against trajectories whose returns are worked out by hand (paper App. D.1)."""

import numpy as np
import pytest

from nmrm_ros.oracles import make_oracle
from nmrm_ros.oracles.lunar_lander import COMPONENTS

T = 100
OUTSIDE = [0.1, 0.5]     # in a spawn zone: no zone of any task
TREASURE = [0.5, 0.8]
KEY = [0.5, 0.2]
CHARGE = [0.1, 0.2]      # y <= 0.3 but outside the key zone


def path(*segments):
    """Concatenate (position, n_steps) segments into states (1, L, 2) float32."""
    states = np.concatenate([np.tile(np.asarray(p, np.float32), (n, 1)) for p, n in segments])
    return states[None]


def test_timer_enter_at_40_and_stay():
    states = path((OUTSIDE, 40), (TREASURE, 60))
    labels = make_oracle("timer").label(states)
    # t = 40..49: h_{t+1} = 41..50 <= 50 -> -1 (10 steps); t = 50..99: +1 (50 steps)
    assert labels.returns[0] == -10 + 50
    assert labels.rewards[0, 49] == -1 and labels.rewards[0, 50] == 1
    assert labels.hidden[0, :, 0].tolist() == list(range(1, 101))


def test_timer_only_before_switch():
    labels = make_oracle("timer").label(path((TREASURE, 50), (OUTSIDE, 50)))
    assert labels.returns[0] == -50


def test_key_treasure_before_and_after_key():
    states = path((TREASURE, 10), (OUTSIDE, 5), (KEY, 3), (OUTSIDE, 2), (TREASURE, 7), (OUTSIDE, 73))
    labels = make_oracle("key").label(states)
    assert labels.returns[0] == 7  # the first 10 treasure steps had no key
    assert labels.hidden[0, 14, 0] == 0 and labels.hidden[0, 15, 0] == 1  # key at t = 15


def test_key_zone_counts_in_the_same_step():
    # h_{t+1} is updated before the reward: the step that enters the key zone already holds it.
    labels = make_oracle("key").label(path((KEY, 1), (OUTSIDE, 99)))
    assert labels.hidden[0, 0, 0] == 1


def test_charger_caps_at_one():
    states = path((CHARGE, 60), (TREASURE, 10), (OUTSIDE, 30))
    labels = make_oracle("charger").label(states)
    assert labels.hidden[0, 49, 0] == 1.0  # 50 charges of 0.02 are exactly 1
    assert labels.hidden[0, :, 0].max() == 1.0
    assert labels.returns[0] == pytest.approx(10.0)


def test_charger_partial_charge():
    labels = make_oracle("charger").label(path((CHARGE, 10), (TREASURE, 5), (OUTSIDE, 85)))
    assert labels.returns[0] == pytest.approx(5 * 0.2)


def test_moving_bounce_points():
    states = path(([0.1, 0.8], T))
    labels = make_oracle("moving").label(states)
    pos, vel = labels.hidden[0, :, 0], labels.hidden[0, :, 1]
    # left edge after step t: 0.4 - 0.02 (t + 1) down to 0 at t = 19, bounce, 0.8 at t = 59, 0 at t = 99
    assert pos[0] == pytest.approx(0.38)
    assert pos[19] == 0.0 and vel[19] == 0.02
    assert pos[59] == 0.8 and vel[59] == -0.02
    assert pos[99] == 0.0 and vel[99] == 0.02
    assert np.all((pos >= 0) & (pos <= 0.8))
    # the agent at x = 0.1 is inside while the left edge is in [0, 0.1]: t = 14..24 and t = 94..99
    expected = np.zeros(T)
    expected[14:25] = 1
    expected[94:100] = 1
    np.testing.assert_array_equal(labels.rewards[0], expected)
    assert labels.returns[0] == 17


def lander_state(x=0.0, y=0.0, vx=0.0, vy=0.0, angle=0.0, vangle=0.0, left=0.0, right=0.0):
    return [x, y, vx, vy, angle, vangle, left, right]


def test_lunar_lander_fifty_on_pad_then_hover():
    on_pad = lander_state(left=1.0, right=1.0)
    hovering = lander_state(y=1.0)
    states = np.array([[on_pad] * 50 + [hovering] * 450], dtype=np.float32)
    oracle = make_oracle("lunar_lander")
    labels = oracle.label(states)
    # t < 49: h_{t+1} < 50: R_pad + R_shaping(y_target=0) = 1 + 0.2
    # t = 49: h = 50, still on the pad: R_no_contact 0 + R_hover 0 + R_shaping(y_target=1) = 0.1
    # t >= 50: airborne at (0, 1): 1 + 1 + 0.2
    assert labels.rewards[0, 0] == pytest.approx(1.2)
    assert labels.rewards[0, 49] == pytest.approx(0.1)
    assert labels.rewards[0, 50] == pytest.approx(2.2)
    assert labels.returns[0] == pytest.approx(49 * 1.2 + 0.1 + 450 * 2.2)
    parts = oracle.label_components(states)
    assert set(parts) == set(COMPONENTS)
    assert parts["pad"][0].sum() == 49 and parts["hover"][0].sum() == 450
    assert parts["no_contact"][0].sum() == 450
    np.testing.assert_allclose(sum(parts.values()), labels.rewards)


def test_lunar_lander_pad_count_caps_at_50():
    states = np.array([[lander_state(left=1.0, right=1.0)] * 80], dtype=np.float32)
    labels = make_oracle("lunar_lander").label(states)
    assert labels.hidden[0, :, 0].max() == 50


def test_tracker_matches_batch_label():
    rng = np.random.default_rng(3)
    states = rng.uniform(0, 1, (1, T, 2)).astype(np.float32)
    for task in ("timer", "moving", "key", "charger"):
        oracle = make_oracle(task)
        labels = oracle.label(states)
        tracker = oracle.tracker()
        for t in range(T):
            r, h = tracker.step(states[0, t])
            assert r == labels.rewards[0, t]
            np.testing.assert_array_equal(h, labels.hidden[0, t])
        assert tracker.total == pytest.approx(labels.returns[0])


def test_bad_states_are_refused():
    oracle = make_oracle("key")
    with pytest.raises(ValueError, match="shape"):
        oracle.label(np.zeros((1, 5, 3), np.float32))
    with pytest.raises(ValueError, match="NaN"):
        oracle.label(np.full((1, 5, 2), np.nan, np.float32))
    with pytest.raises(ValueError, match="no oracle"):
        make_oracle("treasure_hunt")
