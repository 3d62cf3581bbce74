"""The episode ordering rule shared by the reward model, the labeller (and the recorder)."""

import numpy as np

from nmrm_ros.ros.episodes import EpisodeFollower, Kind

A, B = np.array([0.1, 0.2]), np.array([0.3, 0.4])


def test_in_order_duplicates_and_restart():
    f = EpisodeFollower()
    assert f.classify(0, 0, A) is Kind.START
    assert f.classify(0, 0, A) is Kind.DUPLICATE
    assert f.classify(0, 1, B) is Kind.NEXT
    assert f.classify(0, 1, B) is Kind.DUPLICATE
    assert f.classify(0, 2, A) is Kind.NEXT
    assert f.classify(1, 0, B) is Kind.START  # a new episode starts at step 0


def test_gaps_disorder_and_strangers_break_the_episode_once():
    f = EpisodeFollower()
    f.classify(0, 0, A)
    assert f.classify(0, 2, A) is Kind.BROKEN and f.just_broke
    assert f.classify(0, 3, A) is Kind.BROKEN and not f.just_broke  # counted once
    assert f.classify(0, 0, A) is Kind.START  # step 0 again restarts
    f.classify(0, 1, B)
    assert f.classify(0, 1, A) is Kind.BROKEN  # same step, another state
    g = EpisodeFollower()
    assert g.classify(5, 3, A) is Kind.BROKEN  # joined mid-episode
    assert g.classify(6, 0, A) is Kind.START


def test_nothing_after_the_final_step():
    f = EpisodeFollower()
    f.classify(0, 0, A)
    f.classify(0, 1, B)
    f.finish()
    assert f.classify(0, 1, B) is Kind.DUPLICATE
    assert f.classify(0, 2, A) is Kind.BROKEN


def test_break_episode():
    f = EpisodeFollower()
    f.classify(0, 0, A)
    assert f.break_episode(0) and not f.break_episode(0)
    assert f.classify(0, 1, A) is Kind.BROKEN
