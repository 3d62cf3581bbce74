"""RL without ROS: the reward wrappers, the double-DQN target, a short run that must learn, the
`nmrm rl` command line."""

from __future__ import annotations

import copy
import json
import subprocess

import numpy as np
import pytest
import torch

from nmrm_ros.testing.graph import executable
from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import load_checkpoint, load_train_config
from nmrm_ros.mil.checkpoint import checkpoint_paths
from nmrm_ros.mil.online import batched_reference
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.oracles import Oracle, make_oracle
from nmrm_ros.rl import (EpisodeSeeds, NonMarkovianRewardWrapper, OracleRewardWrapper,
                         RewardModelWrapper, double_q_target, evaluate_agent, load_rl_config,
                         make_algorithm, make_reward_env, train_agent)
from nmrm_ros.oracles.base import OracleTracker
from nmrm_ros.tasks import make_env


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """Small CSC models of Key and Timer (a few epochs: only their wiring matters here)."""
    out = {}
    for task in ("key", "timer"):
        ds = generate_screened(task, 200, seed=0)
        path = tmp_path_factory.mktemp("ckpt") / f"{task}_csc"
        out[task] = fit(ds, "csc_lstm", load_train_config(task, max_epochs=2), out=path,
                                       progress=False).checkpoint
    return out


def rollout(env, actions, seed):
    obs, _ = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], []
    for a in actions:
        obs, r, terminated, truncated, info = env.step(a)
        observations.append(obs)
        rewards.append(r)
        infos.append(info)
        if terminated or truncated:
            break
    return np.array(observations), np.array(rewards), infos


def test_model_wrapper_serves_the_online_model_in_figure_2_order(checkpoints):
    model, _ = load_checkpoint(checkpoints["key"])
    actions = np.random.default_rng(1).integers(0, 5, 100)
    plain = EpisodeSeeds(make_env("key"), 7)
    states = [plain.reset()[0]] + [plain.step(a)[0] for a in actions]
    states = np.array(states)                                   # s_0..s_100
    rewards, hidden = batched_reference(model, states)          # r'_t, [h'_{t+1}, c'_{t+1}] for t = 0..100

    env = RewardModelWrapper(EpisodeSeeds(make_env("key"), 7), checkpoints["key"], task="key")
    assert env.observation_space.shape == (6,)
    obs, r, infos = rollout(env, actions, seed=7)
    assert obs.shape == (101, 6)
    np.testing.assert_array_equal(obs[:, :2], states)
    np.testing.assert_allclose(obs[:, 2:], hidden, atol=1e-5)   # [s_t, h'_{t+1}, c'_{t+1}]
    only_h = RewardModelWrapper(EpisodeSeeds(make_env("key"), 7), checkpoints["key"], task="key", served="h")
    assert only_h.observation_space.shape == (4,)
    np.testing.assert_allclose(rollout(only_h, actions, seed=7)[0][:, 2:], hidden[:, :2], atol=1e-5)
    np.testing.assert_allclose(r, rewards[:100], atol=1e-5)     # transition t gets r'_t
    labels = make_oracle("key").label(states[None, :100])
    np.testing.assert_array_equal([i["oracle_reward"] for i in infos], labels.rewards[0])
    assert infos[-1]["oracle_return"] == pytest.approx(labels.returns[0])
    assert infos[-1]["learnt_return"] == pytest.approx(float(np.sum(r)))
    # reset() starts the hidden state again from h'_0
    first_again, _ = env.reset(seed=7)
    np.testing.assert_array_equal(first_again, obs[0])


@pytest.mark.parametrize("hidden", [True, False])
def test_oracle_wrappers_are_the_papers_baselines(hidden):
    actions = np.random.default_rng(2).integers(0, 5, 100)
    env = OracleRewardWrapper(EpisodeSeeds(make_env("timer"), 3), "timer", hidden=hidden)
    obs, r, infos = rollout(env, actions, seed=3)
    assert obs.shape == (101, 3 if hidden else 2)
    labels = make_oracle("timer").label(obs[None, :100, :2])
    np.testing.assert_array_equal(r, labels.rewards[0])
    if hidden:  # Timer's hidden state is the time index h_{t+1} = t + 1
        np.testing.assert_array_equal(obs[:, 2], np.arange(1, 102))
    assert infos[-1]["oracle_return"] == infos[-1]["learnt_return"] == pytest.approx(labels.returns[0])


def test_episode_seeds_follow_env_sim():
    """Episode e resets with seed + e, like env_sim; reset(seed=s) restarts the count."""
    env = EpisodeSeeds(make_env("key"), 5)
    firsts = [env.reset()[0] for _ in range(3)]
    for e, first in enumerate(firsts):
        np.testing.assert_array_equal(first, make_env("key").reset(seed=5 + e)[0])
    np.testing.assert_array_equal(env.reset(seed=5)[0], firsts[0])


def test_wrappers_work_in_sb3_vector_envs(checkpoints):
    from stable_baselines3.common.vec_env import DummyVecEnv

    vec = DummyVecEnv([lambda i=i: make_reward_env("key", "model", checkpoints["key"], seed=100 * i)
                       for i in range(3)])
    obs = vec.reset()
    assert obs.shape == (3, 6)  # [s (2), h' (2), c' (2)]
    for _ in range(100):
        obs, rewards, dones, infos = vec.step(np.array([4, 1, 0]))
    assert dones.all() and all("oracle_return" in i and "terminal_observation" in i for i in infos)
    assert obs.shape == (3, 6)


def test_make_reward_env_refuses_bad_kinds(checkpoints):
    with pytest.raises(ValueError, match="unknown reward kind"):
        make_reward_env("key", "bogus")
    with pytest.raises(ValueError, match="needs a checkpoint"):
        make_reward_env("key", "model")
    with pytest.raises(ValueError, match="trained on task 'key'"):
        make_reward_env("timer", "model", checkpoints["key"])


def test_double_q_target_by_hand():
    q_online = torch.tensor([[1.0, 5.0, 2.0], [0.0, -1.0, 3.0]])
    q_target = torch.tensor([[10.0, 20.0, 30.0], [4.0, 5.0, 6.0]])
    rewards = torch.tensor([[1.0], [0.5]])
    dones = torch.tensor([[0.0], [1.0]])
    y = double_q_target(q_online, q_target, rewards, dones, 0.9)
    # row 0: online argmax = action 1 -> target 20 (plain DQN would take 30); row 1: terminal
    np.testing.assert_allclose(y.numpy(), [[1.0 + 0.9 * 20.0], [0.5]])


def test_double_dqn_train_uses_the_double_target():
    """One gradient step of DoubleDQN equals a hand-made step on the same batch with the double
    target (and differs from SB3's max target). Unbounded: the clipping of targets to the value
    bound is tests/test_agent_trust.py's."""
    env = make_reward_env("key", "oracle", seed=0)
    cfg = load_rl_config("dqn", episodes=2, learning_starts=0, batch_size=8, bound_values=False)
    model = make_algorithm(env, "dqn", cfg, episode_length=100, seed=0)
    model.learn(total_timesteps=20)   # fills the buffer (and trains; we only need the state after)
    state = {k: v.clone() for k, v in model.policy.state_dict().items()}
    opt_state = copy.deepcopy(model.policy.optimizer.state_dict())
    np.random.seed(123)
    torch.manual_seed(123)
    batch = model.replay_buffer.sample(8)
    with torch.no_grad():
        y = double_q_target(model.q_net(batch.next_observations), model.q_net_target(batch.next_observations),
                            batch.rewards, batch.dones, model.gamma)
        plain = batch.rewards + (1 - batch.dones) * model.gamma * model.q_net_target(
            batch.next_observations).max(dim=1, keepdim=True).values
    assert not torch.allclose(y, plain)  # the batch tells the two targets apart
    q = torch.gather(model.q_net(batch.observations), 1, batch.actions.long())
    loss = torch.nn.functional.smooth_l1_loss(q, y)
    model.policy.optimizer.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.policy.parameters(), model.max_grad_norm)
    model.policy.optimizer.step()
    expected = {k: v.clone() for k, v in model.policy.state_dict().items()}
    model.policy.load_state_dict(state)
    model.policy.optimizer.load_state_dict(opt_state)
    np.random.seed(123)
    torch.manual_seed(123)
    model.train(gradient_steps=1, batch_size=8)
    for k, v in model.policy.state_dict().items():
        torch.testing.assert_close(v, expected[k], msg=k)


class _GoRightOracle(Oracle):
    """An easy test task: reward x_t per step (a learnable preference for the right-hand side)."""

    task = "go_right"
    hidden_size = 1

    def initial_hidden(self, n=1):
        return np.zeros((n, 1))

    def step(self, hidden, states, actions=None):
        states = self.check_states(states)
        return hidden + 1.0, states[:, 0].copy()


def test_a_short_run_learns_better_than_random():
    """Double DQN with the paper's network on 10-step episodes of an easy reward: after 3000
    steps the greedy policy's oracle return is well above a random policy's on the same episodes."""
    torch.set_num_threads(1)
    oracle = _GoRightOracle()

    def env(seed):
        base = EpisodeSeeds(make_env("key", episode_length=10), seed)
        return NonMarkovianRewardWrapper(base, OracleTracker(oracle), oracle, augment=False, hidden_size=1)

    cfg = load_rl_config("dqn", episodes=300, exploration_fraction=0.33, learning_starts=200)
    model = make_algorithm(env(0), "dqn", cfg, episode_length=10, seed=0)
    model.learn(total_timesteps=3000)
    result = evaluate_agent(model, "key", episodes=30, seed=10**6, reward="oracle-no-hidden",
                            env=env(10**6))
    print(result.summary())
    assert result.returns.mean() > result.random_returns.mean() + 1.0, result.summary()


def test_a_task_spec_takes_the_your_own_task_changes_of_the_rl_config(tmp_path):
    """The paper's tasks get App. E's section as it is; a task spec (your own task) gets it with the
    changes of its environment's entry, else of `your_own_task`; an explicit override beats both."""
    spec = "nmrm_ros.robots.delivery:DeliveryEnv,max_steps=200,xy=0/1"
    config = tmp_path / "rl.yaml"
    config.write_text("dqn: {learning_rate: 1.0e-3, tau: 5.0e-3}\n"
                      "your_own_task: {dqn: {learning_rate: 3.0e-4}}\n")
    assert load_rl_config("dqn", config, task="key")["learning_rate"] == 1e-3
    assert load_rl_config("dqn", config, task=spec)["learning_rate"] == 3e-4
    assert load_rl_config("dqn", config, task=spec, learning_rate=1e-4)["learning_rate"] == 1e-4
    assert load_rl_config("dqn", config, task=spec, learning_rate=None)["learning_rate"] == 3e-4
    config.write_text("dqn: {learning_rate: 1.0e-3, tau: 5.0e-3}\nyour_own_task: {dqn: {learning_rate: 3.0e-4}}\n"
                      "'nmrm_ros.robots.delivery:DeliveryEnv': {dqn: {tau: 1.0e-2}}\n")
    assert load_rl_config("dqn", config, task=spec) == {"learning_rate": 1e-3, "tau": 1e-2}  # its env's own entry
    assert load_rl_config("dqn", config, task="gym:CartPole-v1")["learning_rate"] == 3e-4
    config.write_text("dqn: {learning_rate: 1.0e-3}\nyour_own_task: {dqn: {learning_rat: 3.0e-4}}\n")
    with pytest.raises(ValueError, match="unknown RL settings"):
        load_rl_config("dqn", config, task=spec)
    shipped = load_rl_config("dqn", task=spec)  # the shipped config: its entry names real settings
    assert set(shipped) == set(load_rl_config("dqn", task="key"))


def nmrm(*args, timeout=120):
    return subprocess.run([executable("nmrm"), "rl", *args], capture_output=True, text=True, timeout=timeout)


def test_cli_train_and_evaluate(tmp_path, checkpoints):
    out = tmp_path / "agent"
    res = nmrm("train", "--task", "key", "--reward", "model", "--checkpoint", str(checkpoints["key"]),
               "--episodes", "3", "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "3 episodes, 300 steps" in res.stdout
    for name in ("policy.zip", "curve.csv", "curve.png", "agent.json"):
        assert (out / name).stat().st_size > 0
    model_meta = json.loads(checkpoint_paths(checkpoints["key"])[1].read_text())
    assert json.loads((out / "agent.json").read_text())["checkpoint_sha256"] == model_meta["weights_sha256"]
    rows = (out / "curve.csv").read_text().splitlines()
    assert rows[0] == "episode,oracle_return,learnt_return,steps,wall_time,q_max,q_spread,value_bound" and len(rows) == 4
    q_spread = [float(r.split(",")[-2]) for r in rows[1:]]  # DQN's Q-values on the states it acted in
    assert all(np.isfinite(q_spread)) and min(q_spread) >= 0.0
    # the bound its targets were clipped to at each episode's end: none before the first training step (128)
    bounds = [float(r.split(",")[-1]) for r in rows[1:]]
    assert np.isnan(bounds[0]) and all(np.isfinite(bounds[1:])) and min(bounds[1:]) >= 0.0
    res = nmrm("evaluate", "--policy", str(out / "policy.zip"), "--task", "key", "--episodes", "3")
    assert res.returncode == 0, res.stderr
    assert "reward model: oracle return over 3 episodes: policy" in res.stdout and "random policy" in res.stdout


@pytest.mark.parametrize("args, message", [
    (["--task", "key", "--reward", "bogus"], "unknown reward kind 'bogus'"),
    (["--task", "key", "--reward", "model"], "needs --checkpoint"),
    (["--task", "nowhere", "--reward", "oracle"], "unknown task 'nowhere'"),
    (["--task", "key", "--reward", "oracle", "--episodes", "0"], "Invalid value for '--episodes'"),
])
def test_cli_train_errors(tmp_path, args, message):
    res = nmrm("train", *args, "--out", str(tmp_path / "x"))
    assert res.returncode != 0
    assert message in res.stderr and "Traceback" not in res.stderr


def test_cli_refuses_a_checkpoint_of_another_task(tmp_path, checkpoints):
    res = nmrm("train", "--task", "key", "--reward", "model", "--checkpoint", str(checkpoints["timer"]),
               "--episodes", "1", "--out", str(tmp_path / "x"))
    assert res.returncode != 0
    assert "trained on task 'timer', not 'key'" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "x").exists()


def test_sac_on_lunar_lander_keeps_the_papers_two_learning_rates():
    """Lunar Lander gets SAC; after training steps the actor's Adam runs at 1e-4, the critic's at
    1e-3 (App. E), alpha fixed at 0.2, and an episode's oracle return reaches the info."""
    torch.set_num_threads(1)
    run = train_agent("lunar_lander", "oracle", episodes=1, seed=0, progress=False, learning_starts=400)
    model = run.model
    assert type(model).__name__ == "SplitLRSAC"
    assert [g["lr"] for g in model.actor.optimizer.param_groups] == [1e-4]
    assert [g["lr"] for g in model.critic.optimizer.param_groups] == [1e-3]
    assert float(model.ent_coef_tensor) == pytest.approx(0.2)
    assert model._n_updates == 100   # steps 400..499 trained, one update each
    assert len(run.curve.records) == 1 and np.isfinite(run.curve.records[0].oracle_return)
    assert model.observation_space.shape == (9,)  # 8-D state + the oracle's time-on-pad counter


def test_threaded_vec_env_equals_dummy_vec_env():
    """The fleet's vectorised env gives exactly DummyVecEnv's observations, rewards, dones and
    infos (terminal observations and resets included)."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from nmrm_ros.ros.topic_vec_env import ThreadedVecEnv

    fns = [lambda i=i: make_reward_env("key", "oracle", seed=10 * i) for i in range(3)]
    dummy, threaded = DummyVecEnv(fns), ThreadedVecEnv(fns)
    dummy.seed(3), threaded.seed(3)
    np.testing.assert_array_equal(dummy.reset(), threaded.reset())
    actions = np.random.default_rng(0).integers(0, 5, size=(250, 3))
    for a in actions:  # 2.5 episodes per env
        want, got = dummy.step(a), threaded.step(a)
        for w, g in zip(want[:3], got[:3]):
            np.testing.assert_array_equal(w, g)
        for w, g in zip(want[3], got[3]):
            assert set(w) == set(g)
            for key in w:
                np.testing.assert_array_equal(w[key], g[key])
    threaded.close()


def test_threaded_vec_env_steps_its_envs_at_once():
    """Four envs whose step takes 0.2 s: one vectorised step takes about one env's time."""
    import time

    import gymnasium as gym

    from nmrm_ros.ros.topic_vec_env import ThreadedVecEnv

    class Slow(gym.Wrapper):
        def step(self, action):
            time.sleep(0.2)
            return self.env.step(action)

    vec = ThreadedVecEnv([lambda: Slow(make_reward_env("key", "oracle", seed=0)) for _ in range(4)])
    vec.reset()
    t0 = time.monotonic()
    vec.step(np.zeros(4, dtype=int))
    assert time.monotonic() - t0 < 0.6  # sequentially: 0.8 s
    vec.close()


def test_a_policy_without_agent_json_is_evaluated_on_its_checkpoints_own_served_state(checkpoints):
    """A trained model object (no agent.json) observed [h', tanh c'] (the checkpoint's default, the
    same size as [h', c']): evaluation must serve it that, not guess [h', c'] from the size; a
    policy of h' alone is still told apart by its size."""
    from nmrm_ros.rl.evaluation import served_state_of

    run = train_agent("key", "model", checkpoint=checkpoints["key"], episodes=1, seed=0, progress=False)
    assert run.model.observation_space.shape == (2 + 4,)
    assert served_state_of(run.model, "key", checkpoints["key"], {}) == "h_tanh_c"
    run = train_agent("key", "model", checkpoint=checkpoints["key"], episodes=1, seed=0, progress=False, served="h")
    assert served_state_of(run.model, "key", checkpoints["key"], {}) == "h"


def test_lunar_lander_episodes_report_the_oracles_four_reward_components():
    """The paper's Figure 10 decomposes Lunar Lander returns into pad, no_contact, hover and
    shaping: every episode's info carries them, and they sum to its oracle return."""
    env = make_reward_env("lunar_lander", "oracle", seed=4)
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    while True:
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            break
    parts = info["oracle_components"]
    assert set(parts) == {"pad", "no_contact", "hover", "shaping"}
    assert sum(parts.values()) == pytest.approx(info["oracle_return"], rel=1e-9, abs=1e-9)
