"""Label swapping (paper Sec. 5.2): offline on datasets and in training, online in labeller_oracle."""

from __future__ import annotations

import signal
from collections import Counter

import numpy as np
import pytest
from rclpy.duration import Duration

from nmrm_ros.datasets import OnlineLabelSwapper, make_toy_dataset, swap_labels, swap_sources
from nmrm_ros.mil import load_train_config
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.oracles import make_oracle


@pytest.mark.parametrize("p", [0.0, 0.1, 0.3, 0.5, 1.0])
def test_swapping_keeps_the_labels_and_moves_exactly_the_fraction(p):
    rng = np.random.default_rng(3)
    n = 1000
    returns = rng.integers(0, 50, n).astype(float)
    source = swap_sources(n, p, np.random.default_rng(7))
    assert sorted(source) == list(range(n))  # a permutation: the multiset of labels is kept
    assert int((source != np.arange(n)).sum()) == round(p * n)
    noisy = swap_labels(returns, p, np.random.default_rng(7))
    np.testing.assert_array_equal(noisy, returns[source])
    assert Counter(noisy) == Counter(returns)


def test_swapping_refuses_bad_fractions():
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        swap_sources(10, 1.5, np.random.default_rng(0))
    with pytest.raises(ValueError, match="nothing to swap it with"):
        swap_sources(10, 0.1, np.random.default_rng(0))


def test_training_sees_swapped_labels_and_tests_on_clean_ones():
    ds = make_toy_dataset("push_switch", 300, seed=0)
    runs = {p: fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=3,
                                                                  label_swap=p), progress=False)
            for p in (0.0, 0.5)}
    clean = fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=3), progress=False)
    noisy = runs[0.5]
    # same seeds: only the labels differ, so the training (and validation) losses differ
    assert noisy.train.history[0]["train_loss"] != clean.train.history[0]["train_loss"]
    assert runs[0.0].train.history == clean.train.history
    assert noisy.test_metrics["bags"] == clean.test_metrics["bags"]


def test_online_swapper_publishes_true_returns_about_once_each():
    rng = np.random.default_rng(0)
    truth = list(rng.normal(size=2000))
    swapper = OnlineLabelSwapper(0.3, 20, np.random.default_rng(1))
    published = [swapper.label(r) for r in truth]
    assert published[:20] == truth[:20]  # the pool fills first
    assert set(published) <= set(truth)
    moved = sum(p != t for p, t in zip(published, truth))
    assert moved == swapper.swapped and 0.25 < moved / (2000 - 20) < 0.35
    # the published multiset is the true one but for at most 2 * pool labels
    difference = (Counter(published) - Counter(truth)) + (Counter(truth) - Counter(published))
    assert sum(difference.values()) <= 2 * 2 * 20


def test_labeller_oracle_swaps_labels_over_real_topics(ros_domain):
    """20 episodes published to a real labeller_oracle with label_noise swap: one label each, every
    label some episode's true return, about half of them another episode's."""
    from nmrm_ros.testing.graph import Capture, finish, start
    from nmrm_msgs.msg import EnvObservation
    from nmrm_ros.ros.topics import OBSERVATION

    capture = Capture()
    try:
        labeller = start("labeller_oracle", task="key", label_noise="swap", label_swap=0.5,
                         swap_pool=5, noise_seed=3)
        pub = capture.publisher(EnvObservation, OBSERVATION)
        capture.wait_for_publishers({"label": 1, "oracle_step": 1})
        assert capture.spin_until(lambda: pub.get_subscription_count() >= 1, 30)
        rng = np.random.default_rng(0)
        oracle = make_oracle("key")
        truth = []
        for e in range(20):
            # paths that visit the key and the treasure for a while, so the returns differ
            states = np.clip(np.cumsum(rng.normal(0, 0.08, (101, 2)), axis=0) + [0.5, 0.2], 0, 1)
            states[30:30 + e] = [0.5, 0.8]
            truth.append(oracle.label(states[None, :100]).returns[0])
            for t, s in enumerate(states.astype(np.float32)):
                pub.publish(EnvObservation(task="key", episode=e, step=t, state=s.tolist(),
                                           truncated=(t == 100)))
        assert pub.wait_for_all_acked(Duration(seconds=30))
        assert capture.spin_until(lambda: len(capture.msgs["label"]) >= 20, 30)
        labeller.send_signal(signal.SIGINT)
        code, out = finish(labeller)
    finally:
        capture.close()
    labels = {m.episode: m.return_value for m in capture.msgs["label"]}
    assert sorted(labels) == list(range(20))
    truth32 = [float(np.float32(v)) for v in truth]
    assert all(v in truth32 for v in labels.values())
    swapped = sum(labels[e] != truth32[e] for e in range(20))
    assert [labels[e] for e in range(5)] == truth32[:5]  # the pool fills first
    assert 2 <= swapped <= 13, (swapped, labels, truth32)
    assert code == 0 and f"labelled 20 episode(s), 0 broken, " in out, out
