"""Property tests (hypothesis) of the oracles over random trajectories."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from nmrm_ros.oracles import make_oracle
from nmrm_ros.tasks.navigation import KEY_ZONE

coords = st.floats(0.0, 1.0, width=32)
trajectories = st.integers(1, 120).flatmap(
    lambda n: arrays(np.float32, (1, n, 2), elements=coords))


@settings(max_examples=200, deadline=None)
@given(trajectories)
def test_key_returns_zero_unless_key_zone_visited(states):
    labels = make_oracle("key").label(states)
    if not KEY_ZONE.contains(states[0]).any():
        assert labels.returns[0] == 0
    assert labels.returns[0] >= 0


@settings(max_examples=200, deadline=None)
@given(trajectories)
def test_charger_hidden_state_in_unit_interval(states):
    labels = make_oracle("charger").label(states)
    h = labels.hidden[0, :, 0]
    assert np.all((h >= 0) & (h <= 1))
    assert np.all(np.diff(h) >= 0)  # charge never drains


def _in_treasure(x, y, left=0.4):
    return left <= x <= left + 0.2 and 0.7 <= y <= 0.9


def _paper_return(task: str, states: np.ndarray) -> float:
    """The return of one trajectory written straight from the paper's App. D.1 definitions, step
    by step in plain Python (an independent check of the vectorised oracles)."""
    total, key, charge = 0.0, False, 0.0
    left, velocity = 0.4, -0.02
    for t, (x, y) in enumerate(states.astype(np.float64)):
        if task == "timer":  # h_{t+1} = t + 1; -1 in the treasure while h_{t+1} <= 50, +1 after
            total += (-1.0 if t + 1 <= 50 else 1.0) * _in_treasure(x, y)
        elif task == "key":
            key = key or (0.4 <= x <= 0.6 and 0.1 <= y <= 0.3)
            total += float(key and _in_treasure(x, y))
        elif task == "charger":
            if y <= 0.3:
                charge = min(round(charge + 0.02, 10), 1.0)
            total += charge * _in_treasure(x, y)
        elif task == "moving":
            left = round(left + velocity, 10)
            if not 0.0 < left < 0.8:
                velocity = -velocity
            total += float(_in_treasure(x, y, left))
    return total


@settings(max_examples=100, deadline=None)
@given(trajectories, st.sampled_from(["timer", "moving", "key", "charger"]))
def test_returns_match_the_papers_definitions(states, task):
    labels = make_oracle(task).label(states)
    # equal up to float rounding: Charger's charge is summed in another order by the vectorised
    # oracle (7 charges: 0.13999999999999999 there, 0.14 here), 1 ulp per step at most
    assert labels.returns[0] == pytest.approx(_paper_return(task, states[0]), rel=1e-12, abs=1e-12)


def test_paper_returns_by_hand():
    """A few trajectories whose returns are known without any code."""
    treasure, key_zone, elsewhere = [0.5, 0.8], [0.5, 0.2], [0.1, 0.5]
    path = np.array([[elsewhere] * 10 + [treasure] * 50 + [key_zone] * 5 + [treasure] * 35], np.float32)
    # timer: steps 10..49 are t+1 <= 50 (40 x -1), 50..59 and 65..99 after (45 x +1)
    assert make_oracle("timer").label(path).returns[0] == 5.0
    # key: the treasure counts only after the key (35 steps)
    assert make_oracle("key").label(path).returns[0] == 35.0
    # charger: 5 steps in the key zone (y <= 0.3) charge 0.1; 35 treasure steps at 0.1
    assert np.isclose(make_oracle("charger").label(path).returns[0], 3.5)


lander_states = st.integers(1, 80).flatmap(lambda n: arrays(
    np.float32, (1, n, 8), elements=st.floats(-2.0, 2.0, width=32)))


@settings(max_examples=100, deadline=None)
@given(lander_states, st.lists(st.booleans(), min_size=160, max_size=160))
def test_lunar_lander_components_sum_to_reward(states, contacts):
    c = np.asarray(contacts, np.float32).reshape(80, 2)[: states.shape[1]]
    states = states.copy()
    states[0, :, 6:] = c
    oracle = make_oracle("lunar_lander")
    labels = oracle.label(states)
    parts = oracle.label_components(states)
    np.testing.assert_allclose(sum(parts.values()), labels.rewards)
    assert np.all(labels.rewards >= 0)
