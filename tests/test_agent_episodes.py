"""A trained agent's episodes as a dataset pool (the paper's recycled oracle-agent episodes)."""

import subprocess

import numpy as np
import pytest
import torch
from nmrm_ros.testing.graph import executable

from nmrm_ros.rl.agent_episodes import AgentEpisodes, rollout_agent
from nmrm_ros.datasets.screening import screen_lunar_lander
from nmrm_ros.rl import train_agent


@pytest.fixture(scope="module")
def oracle_agent(tmp_path_factory):
    """A (barely trained) SAC agent of Lunar Lander's oracle, saved as `nmrm rl train` saves it."""
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("agent")
    train_agent("lunar_lander", "oracle", episodes=1, seed=0, out=out, progress=False, learning_starts=400)
    return out / "policy.zip"


def test_agent_episodes_are_plain_states_and_seeded(oracle_agent):
    episodes = rollout_agent(oracle_agent, "lunar_lander", 2, seed=3)
    assert len(episodes) == 2
    for states, actions, terminated in episodes:
        assert states.shape[1] == 8 and actions.shape == (len(states) - 1, 2)  # nothing appended
        assert isinstance(terminated, bool)
    again = rollout_agent(oracle_agent, "lunar_lander", 2, seed=3)
    for (a, _, _), (b, _, _) in zip(episodes, again):
        np.testing.assert_array_equal(a, b)
    told_early = rollout_agent(oracle_agent, "lunar_lander", 2, seed=3, early=40)
    assert any(not np.array_equal(a, b) for (a, _, _), (b, _, _) in zip(episodes, told_early))


def test_bad_agents_are_one_line_errors(oracle_agent, tmp_path):
    with pytest.raises(ValueError, match="trained on task 'lunar_lander', not 'key'"):
        rollout_agent(oracle_agent, "key", 1)
    with pytest.raises(ValueError, match="early must be >= 0"):
        rollout_agent(oracle_agent, "lunar_lander", 1, early=-1)
    with pytest.raises(ValueError, match="no policy file"):
        rollout_agent(tmp_path / "missing.zip", "lunar_lander", 1)


def test_lunar_lander_pool_with_agent_episodes(oracle_agent):
    ds = screen_lunar_lander(pool_size=6, seed=0, n_target=4, agent=AgentEpisodes(oracle_agent), agent_fraction=0.5)
    assert len(ds) == 4 and ds.meta["agent"] == str(oracle_agent) and ds.meta["agent_fraction"] == 0.5
    with pytest.raises(ValueError, match="agent_fraction must be in"):
        screen_lunar_lander(pool_size=6, seed=0, n_target=4, agent=AgentEpisodes(oracle_agent), agent_fraction=0.0)


def test_dataset_screen_takes_an_oracle_agent_into_lunar_landers_pool(oracle_agent, tmp_path):
    """`nmrm dataset screen --task lunar_lander --policy P`: P's episodes join the scripted pool;
    an agent of another task is a one-line error and writes nothing."""
    out = tmp_path / "ll.npz"
    res = subprocess.run([executable("nmrm"), "dataset", "screen", "--task", "lunar_lander", "--n", "4",
                          "--pool-size", "10", "--policy", str(oracle_agent), "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    from nmrm_ros.datasets import TrajectoryDataset

    assert TrajectoryDataset.load(out).meta["agent"] == str(oracle_agent)
    key_agent = tmp_path / "key"
    train_agent("key", "oracle", episodes=1, seed=0, out=key_agent, progress=False)
    res = subprocess.run([executable("nmrm"), "dataset", "screen", "--task", "lunar_lander", "--n", "4",
                          "--pool-size", "10", "--policy", str(key_agent / "policy.zip"),
                          "--out", str(tmp_path / "bad.npz")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and "trained on task 'key', not 'lunar_lander'" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr and not (tmp_path / "bad.npz").exists()
