"""Task environments: dynamics, seeding, episode ends, the registry."""

import numpy as np
import pytest

from nmrm_ros.tasks import TASKS, make_env, task_info
from nmrm_ros.tasks.navigation import SPAWN_ZONES, NavigationSimulator, rollout_random


def run_episode(env, seed, policy_seed=0):
    rng = np.random.default_rng(policy_seed)
    obs, _ = env.reset(seed=seed)
    states = [obs]
    done = False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(_sample(env, rng))
        assert reward == 0.0
        states.append(obs)
        done = terminated or truncated
    return np.asarray(states), terminated, truncated


def _sample(env, rng):
    if env.action_space.shape == ():
        return int(rng.integers(env.action_space.n))
    return rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)


@pytest.mark.parametrize("task", ["timer", "key"])
def test_navigation_episode(task):
    env = make_env(task)
    states, terminated, truncated = run_episode(env, seed=1)
    assert states.shape == (101, 2) and states.dtype == np.float32
    assert truncated and not terminated
    assert np.all((states >= 0) & (states <= 1))
    assert any(z.contains(states[0]) for z in SPAWN_ZONES)
    step = np.abs(np.diff(states.astype(np.float64), axis=0)).max()
    assert step < 0.1 + 5 * 0.02  # one move plus noise at most
    with pytest.raises(RuntimeError):
        env.step(0)


def test_same_seed_same_trajectory_bit_for_bit():
    for task in ("charger", "lunar_lander"):
        a = run_episode(make_env(task), seed=7)[0]
        b = run_episode(make_env(task), seed=7)[0]
        c = run_episode(make_env(task), seed=8)[0]
        assert a.tobytes() == b.tobytes()
        assert a.shape != c.shape or a.tobytes() != c.tobytes()


def test_motion_and_noise():
    sim = NavigationSimulator(20000, np.random.default_rng(0))
    sim.positions[:] = 0.5
    new = sim.step(np.full(20000, 4))  # right
    d = new.astype(np.float64) - 0.5
    assert abs(d[:, 0].mean() - 0.1) < 1e-3 and abs(d[:, 1].mean()) < 1e-3
    assert abs(d[:, 0].std() - 0.02) < 1e-3 and abs(d[:, 1].std() - 0.02) < 1e-3
    with pytest.raises(ValueError):
        sim.step(np.full(20000, 5))
    with pytest.raises(ValueError):
        sim.step(np.full(20000, np.nan))


def test_spawn_zones_half_each():
    states, _ = rollout_random(20000, np.random.default_rng(1), length=1)
    left = SPAWN_ZONES[0].contains(states[:, 0])
    right = SPAWN_ZONES[1].contains(states[:, 0])
    assert np.all(left | right)
    assert abs(left.mean() - 0.5) < 0.02


def test_continuous_variant():
    env = make_env("moving", continuous=True)
    states, _, truncated = run_episode(env, seed=2)
    assert truncated and states.shape == (101, 2)


def test_lunar_lander_rest_does_not_end_episode_but_leaving_screen_does():
    env = make_env("lunar_lander")
    obs, _ = env.reset(seed=0)
    # engines off: the lander falls, lands (or crashes) and rests, the episode goes on to T
    for _ in range(500):
        obs, _, terminated, truncated, _ = env.step(np.array([-1.0, 0.0], np.float32))
        assert not terminated
    assert truncated and (obs[6] == 1.0 or obs[7] == 1.0)
    # full side engine: the lander drifts off the screen and the episode terminates early
    obs, _ = env.reset(seed=0)
    for t in range(500):
        obs, _, terminated, truncated, _ = env.step(np.array([0.0, 1.0], np.float32))
        if terminated:
            break
    assert terminated and abs(obs[0]) >= 1.0 and t < 499
    with pytest.raises(ValueError):
        env.step(np.array([np.nan, 0.0]))


def test_registry():
    assert set(TASKS) == {"timer", "moving", "key", "charger", "lunar_lander", "timer_pixels", "moving_pixels",
                          "key_pixels", "charger_pixels"}
    assert task_info("lunar_lander").state_size == 8
    assert task_info("key").action_size == 5
    with pytest.raises(ValueError, match="unknown task"):
        make_env("maze")
