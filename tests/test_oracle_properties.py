"""Property tests (hypothesis) of the oracles over random trajectories."""

import numpy as np
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


@settings(max_examples=100, deadline=None)
@given(trajectories, st.sampled_from(["timer", "moving", "key", "charger"]))
def test_rewards_sum_to_return(states, task):
    labels = make_oracle(task).label(states)
    assert np.isclose(labels.rewards.sum(), labels.returns[0])


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
    assert np.isclose(labels.rewards.sum(), labels.returns[0])
