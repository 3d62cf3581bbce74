"""An agent a user can trust (issue 50): values bounded by what the rewards allow, the kept policy
is not the collapsed or the reward-hacked one, collapses reported, and `nmrm check` says what to
run next when it fails."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from nmrm_ros.rl import DoubleDQN, EpisodeCurveCallback, LearningCurve
from nmrm_ros.rl.acceptance import HackingCheck, MemoryCheck, next_step
from nmrm_ros.rl.model_check import AgentEpisodesCheck, model_check_of_run
from nmrm_ros.rl.collapse import collapse_report, late_dip
from nmrm_ros.rl.kept_policy import PolicyKeeper, episode_scores
from nmrm_ros.rl.training import EpisodeRecord
from nmrm_ros.rl.value_bound import ValueBound


def test_value_bound_is_the_geometric_series_of_the_rewards_seen():
    b = ValueBound.of(np.array([0.0, 0.5, 1.0]), 0.99)
    assert b.high == pytest.approx(100.0) and b.low == 0.0
    b = ValueBound.of(np.array([-2.0, 3.0]), 0.9)
    assert (b.low, b.high) == (pytest.approx(-20.0), pytest.approx(30.0))
    assert ValueBound.of(np.zeros(0), 0.99).high == 0.0  # nothing paid yet: nothing to earn
    with pytest.raises(ValueError, match="discount"):
        ValueBound.of(np.ones(3), 1.0)


class Chain(gym.Env):
    """A corridor of cells -6..6, start at 0, 20 steps, actions left / right. The judge (oracle)
    pays 1 a step at cell +2; the 'reward model' pays that too, and 3 a step at cell -6, a cell
    the judge does not pay: a model that overpays an unseen state, built on purpose."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, hack: float = 3.0) -> None:
        self.hack = hack

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t, self.returns = 0, 0, [0.0, 0.0]
        return np.array([self.x / 6], np.float32), {}

    def step(self, action):
        self.x = int(np.clip(self.x + (1 if action == 1 else -1), -6, 6))
        self.t += 1
        judged = 1.0 if self.x == 2 else 0.0
        learnt = judged + (self.hack if self.x == -6 else 0.0)
        self.returns[0] += learnt
        self.returns[1] += judged
        done = self.t >= 20
        info = {"learnt_return": self.returns[0], "oracle_return": self.returns[1]} if done else {}
        return np.array([self.x / 6], np.float32), learnt, False, done, info


def _learn(env, seed: int, keeper, episodes: int, **kwargs):
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)
    model = DoubleDQN("MlpPolicy", DummyVecEnv([lambda: env]), seed=seed, device="cpu", learning_rate=1e-3,
                      buffer_size=10_000, learning_starts=100, batch_size=64, gamma=0.95, train_freq=1,
                      gradient_steps=1, target_update_interval=1, tau=0.01, exploration_fraction=0.5,
                      exploration_final_eps=0.05, policy_kwargs={"net_arch": [32, 32]}, **kwargs)
    callback = EpisodeCurveCallback(max_episodes=episodes, keeper=keeper)
    model.learn(total_timesteps=episodes * 20 + 1, callback=callback)
    return model, callback


def _greedy_cell(model) -> int:
    env = Chain()
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        obs, *_ = env.step(model.predict(obs, deterministic=True)[0])
    return env.x


def test_a_hacked_model_does_not_make_its_policy_kept_and_values_stay_bounded():
    keeper = PolicyKeeper(every=10)
    model, callback = _learn(Chain(), 0, keeper, episodes=150)
    records = callback.curve.records
    # the agent found the overpaid cell: late episodes earn the model's 3 a step, not the judge's 1
    late = records[-20:]
    assert np.mean([r.learnt_return for r in late]) > 30 and np.mean([r.oracle_return for r in late]) < 5
    assert _greedy_cell(model) == -6
    # its values never left what the rewards allow: at most 3 / (1 - 0.95) = 60
    bound = model.value_bound
    assert bound.high == pytest.approx(60.0)
    with torch.no_grad():
        q = model.q_net(torch.linspace(-1, 1, 13)[:, None]).numpy()
    assert q.max() <= bound.high * 1.01
    # the kept policy is the one the model and the judge both rate: it goes to cell +2
    kept = keeper.kept()
    assert kept is not None
    model.policy.load_state_dict(kept.weights)
    assert _greedy_cell(model) == 2


def test_targets_are_clipped_to_the_bound():
    """A target network whose values ran away (1000) gives targets of at most the bound."""
    env = Chain(hack=0.0)
    model, _ = _learn(env, 1, None, episodes=6)
    with torch.no_grad():
        for p in model.q_net_target.parameters():
            p.zero_()
        model.q_net_target.q_net[-1].bias.fill_(1000.0)
    before = model.targets_clipped
    model.train(gradient_steps=1, batch_size=64)
    assert model.targets_clipped > before
    assert model.value_bound.high == pytest.approx(1.0 / 0.05)
    off = DoubleDQN("MlpPolicy", env, bound_values=False, device="cpu", learning_starts=0)
    assert off.value_bound is None


def test_keeper_keeps_the_last_policy_when_nothing_collapsed():
    class Fake:
        def __init__(self):
            self.policy = torch.nn.Linear(1, 1)

    keeper, model = PolicyKeeper(every=10), Fake()
    for e in range(100):  # learning, then a plateau
        keeper.on_episode(model, learnt=min(e, 60), judged=min(e, 60) + 1.0)
    assert keeper.kept() is None and keeper.summary()["is_last"]


def test_keeper_keeps_the_policy_before_a_collapse_and_skips_windows_beyond_the_bound():
    class Fake:
        def __init__(self):
            self.policy = torch.nn.Linear(1, 1)

    keeper, model = PolicyKeeper(every=10), Fake()
    curve = [min(e, 50) for e in range(60)] + [55] * 20 + [0] * 20  # learnt, peaked, lost
    for e, g in enumerate(curve):
        with torch.no_grad():
            model.policy.bias.fill_(float(e))
        # episodes 60-69 looked best, but their values had run away
        keeper.on_episode(model, learnt=g + (100 if 60 <= e < 70 else 0), judged=g,
                          q_max=500.0 if 60 <= e < 70 else 50.0, bound_high=100.0)
    kept = keeper.kept()
    assert kept is not None and kept.episode == 70  # the snapshot after episode 70 scored 70-79
    assert float(kept.weights["bias"]) == 69.0
    assert keeper.summary()["windows_beyond_bound"] == 1


def test_episode_scores_need_both_judges():
    learnt = np.array([0.0, 10.0, 50.0])
    judged = np.array([0.0, 10.0, 0.0])  # the last episode is overpaid by the model
    s = episode_scores(learnt, judged)
    assert s[2] == 0.0 and s[1] == pytest.approx(0.2)
    assert episode_scores(learnt, np.full(3, np.nan)).tolist() == [0.0, 0.2, 1.0]


def _curve(oracle, learnt=None, q=None, bounds=None) -> LearningCurve:
    learnt = oracle if learnt is None else learnt
    return LearningCurve([EpisodeRecord(i, float(o), float(g), 100, 0.0,
                                        q=({"q_max": float(q[i]), "q_spread": 1.0} | (
                                            {} if bounds is None else {"value_bound": float(bounds[i])}))
                                        if q is not None else {})
                          for i, (o, g) in enumerate(zip(oracle, learnt))])


def test_values_are_judged_against_the_bound_of_their_own_episode():
    """The bound moves (rewards enter and leave the buffer; the loop swaps the model): the patrol
    loop's agent seed 1 peaked at Q 104 in round 2, whose model allowed ~106, and was called
    collapsed against the last model's 102."""
    healthy = np.concatenate([np.linspace(0, 80, 150), np.full(250, 80.0)])
    q = np.concatenate([np.linspace(0, 100, 300), np.full(100, 95.0)])
    q[297] = 104.0
    moving = np.where(np.arange(400) < 300, 106.0, 102.0)
    report = collapse_report(_curve(healthy, q=q, bounds=moving), bound_high=102.0)
    assert not report.collapsed and report.q_episode == 297
    assert "max Q 104 (episode 297) within its bound 106" in report.summary()
    # ... and a peak beyond the bound of its time is one, whatever the bound at the end
    rising = np.where(np.arange(400) < 300, 100.0, 110.0)
    report = collapse_report(_curve(healthy, q=q, bounds=rising), bound_high=110.0)
    assert report.collapsed and report.q_beyond_bound and report.q_episode == 297
    assert "max Q reached 104 at episode 297, beyond the 100 the rewards allowed then" in report.summary()
    # the first episodes, before any training step, have no bound of their own: the given one judges
    early = np.full(400, np.nan)
    early[300:] = 102.0
    assert not collapse_report(_curve(healthy, q=np.minimum(q, 101.0), bounds=early), bound_high=102.0).collapsed


def test_an_untrained_networks_values_over_the_first_rewards_tiny_bound_are_not_a_runaway():
    """Patrol robot, a 16-unit model paying ~2e-4 a step at first: at episode 0 the buffer's
    rewards allowed 0.02 and the untrained network's mean max Q was 0.07; the run's bound is 100.
    Judged by 1% of the run's largest bound, that is no collapse, and the window is scored."""
    healthy = np.concatenate([np.linspace(0, 80, 150), np.full(250, 80.0)])
    q = np.concatenate([[0.07, 0.05], np.linspace(0.5, 70, 398)])
    bounds = np.concatenate([[0.02, 0.03], np.full(398, 100.0)])
    report = collapse_report(_curve(healthy, q=q, bounds=bounds), bound_high=100.0)
    assert not report.collapsed and not report.q_beyond_bound, report.summary()
    assert "max Q 70 (episode 399) within its bound 100" in report.summary()  # the largest, not episode 0's
    # when the largest is episode 0's, above its tiny bound by less than the margin, the line says so
    flat = np.concatenate([[0.07], np.full(399, 0.01)])
    summary = collapse_report(_curve(healthy, q=flat, bounds=bounds), bound_high=100.0).summary()
    assert ("max Q 0.07 (episode 0) above its bound then (0.02) by less than 1% of the run's largest "
            "bound (100): not a runaway") in summary, summary
    # a value that does run away, early or late, still is one
    q_run = q.copy()
    q_run[1] = 5.0
    assert collapse_report(_curve(healthy, q=q_run, bounds=bounds), bound_high=100.0).q_beyond_bound

    class Fake:
        policy = torch.nn.Linear(1, 1)

    keeper = PolicyKeeper(every=2)
    for e in range(6):
        keeper.on_episode(Fake(), learnt=float(e), judged=float(e), q_max=float(q[e]),
                          bound_high=float(bounds[e]))
    assert all(np.isfinite(s.score) for s in keeper._score())

def test_collapse_report_on_a_scripted_curve():
    rise = np.linspace(0, 80, 150)
    healthy = np.concatenate([rise, np.full(250, 80.0)])
    report = collapse_report(_curve(healthy, q=np.linspace(0, 70, 400)), bound_high=100.0)
    assert not report.collapsed
    assert report.summary().startswith("no collapse") and "within its bound 100" in report.summary()

    dipped = np.concatenate([rise, np.full(150, 80.0), np.full(100, 2.0)])
    report = collapse_report(_curve(dipped, q=np.linspace(0, 300, 400)), bound_high=100.0, kept_episode=280)
    assert report.collapsed and report.dip is not None and report.q_beyond_bound
    line = report.summary()
    assert "\n" not in line and line.startswith("learning collapsed: the oracle return fell from 80")
    assert "max Q reached 300, beyond the 100 the rewards allow" in line
    assert "kept the policy of episode 280" in line
    # without oracle labels (a graph without a labeller) the learnt return is judged
    report = collapse_report(_curve(np.full(400, np.nan), learnt=dipped))
    assert report.judged_by == "learnt" and report.dip is not None
    # a run that never learnt did not collapse
    assert late_dip(np.zeros(400), 50) is None
    # ... nor one whose best window is within the noise of its random first episodes (Key, an agent
    # on a model whose served state forgot the key: 0.56 at first, 1.52 at best, then 0): it is
    # said to have learnt nothing
    lucky = np.where(np.arange(400) % 20 == 0, 10.0, 0.0)  # a random policy's rare paid episodes
    lucky[130:180] = np.where(np.arange(50) % 7 == 0, 10.0, 0.0)  # a lucky stretch: 1.4 against 0.5
    lucky[200:] = 0.0
    report = collapse_report(_curve(lucky, q=np.linspace(0, 190, 400)), bound_high=287.0)
    assert not report.collapsed and not report.learnt
    assert report.summary().startswith("did not learn: the best 50 episodes' oracle return")
    assert collapse_report(_curve(dipped)).learnt and collapse_report(_curve(healthy)).learnt
    # a run that learnt within its first window and then lost it all did collapse
    early = np.concatenate([np.zeros(8), np.full(242, 100.0), np.zeros(150)])
    assert collapse_report(_curve(early)).collapsed


def test_check_failure_names_the_next_command():
    hacked = HackingCheck(79.0, 37.4, 10.0, 10.0, 1.0, 40.0, 50)
    memory = MemoryCheck(100, 0.95, 0.9)
    text = next_step([memory, hacked], "runs/mine", "my.tasks:Env,speed=2", "my/oracle.py:oracle")
    assert "nmrm loop --task my.tasks:Env,speed=2 --oracle my/oracle.py:oracle" in text
    assert "label.launch.yaml" in text and "policy:=learn" in text and "checkpoint:=runs/mine" in text
    text = next_step([MemoryCheck(100, 0.5, 0.4)], "runs/key", "key")
    assert "larger hidden state" in text and "nmrm loop --task key --rounds" in text
    assert math.isfinite(hacked.gap)


def test_rl_train_ends_by_checking_the_model_where_the_agent_went(small_key_checkpoint, tmp_path):
    """`nmrm rl train --reward model` compares what the model paid the agent's last episodes with
    the oracle's returns of them (agent.json records it); a model that overpays them fails, with
    the loop as the next command; a model of comparisons (other units) is not compared."""
    import json
    import shutil
    import subprocess

    from nmrm_ros.testing.graph import executable

    res = subprocess.run([executable("nmrm"), "rl", "train", "--task", "key", "--reward", "model", "--checkpoint",
                          str(small_key_checkpoint), "--episodes", "3", "--out", str(tmp_path / "a")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "the model on the agent's last 3 episodes: paid" in res.stdout, res.stdout
    check = json.loads((tmp_path / "a" / "agent.json").read_text())["model_check"]
    assert check["episodes"] == 3 and isinstance(check["passed"], bool)
    judged = np.full(60, 37.4)
    hacked = model_check_of_run(small_key_checkpoint, judged + 41.6, judged)
    assert isinstance(hacked, AgentEpisodesCheck) and hacked.episodes == 50 and not hacked.passed
    assert hacked.summary().endswith("FAIL: the agent went where the model is wrong")
    assert "nmrm loop --task key" in next_step([hacked], "runs/key", "key")
    assert model_check_of_run(small_key_checkpoint, judged, judged).passed
    assert model_check_of_run(small_key_checkpoint, judged, np.full(60, np.nan)) is None  # nobody judged
    record = json.loads(small_key_checkpoint.with_suffix(".json").read_text())
    record["train_config"]["feedback"] = "preferences"
    shutil.copy(small_key_checkpoint.with_suffix(".pt"), tmp_path / "prefs.pt")
    (tmp_path / "prefs.json").write_text(json.dumps(record))
    assert model_check_of_run(tmp_path / "prefs", judged + 41.6, judged) is None
    record["train_config"]["feedback"] = "returns"
    record["calibration"] = {"gain": 2.0, "offset": 0.0}  # its recorded RMSE predates the calibration
    (tmp_path / "prefs.json").write_text(json.dumps(record))
    assert model_check_of_run(tmp_path / "prefs", judged + 41.6, judged) is None
    del record["calibration"]
    record["metrics"]["val"]["return_mse"] = float("nan")  # no return labels validated it
    (tmp_path / "prefs.json").write_text(json.dumps(record))
    assert model_check_of_run(tmp_path / "prefs", judged, judged) is None


def test_a_policy_is_kept_with_the_model_it_acted_on():
    """The loop swaps reward models: a snapshot carries the model it was served, and no scored
    window spans a swap."""
    class Fake:
        def __init__(self):
            self.policy = torch.nn.Linear(1, 1)

    keeper, model = PolicyKeeper(every=10), Fake()
    keeper.tag = "model_0"
    for e in range(105):
        if e == 55:  # a swap in the middle of a window: the snapshot of episode 50 is dropped
            keeper.retag("model_1", model)
        g = 80.0 if 55 <= e < 65 else 10.0
        keeper.on_episode(model, learnt=g, judged=g)
    assert [s.episode for s in keeper.snapshots][:7] == [10, 20, 30, 40, 55, 60, 70]
    kept = keeper.kept()
    assert kept.episode == 55 and kept.tag == "model_1" and keeper.summary()["tag"] == "model_1"


class Line(gym.Env):
    """A continuous 1-D task: 10 steps, reward 1 - |x| in [0, 1]."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.5, 0
        return np.array([self.x], np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + 0.2 * float(action[0]), -1, 1))
        self.t += 1
        return np.array([self.x], np.float32), 1.0 - abs(self.x), False, self.t >= 10, {}


def test_sac_target_critics_are_clipped_to_the_soft_value_bound(tmp_path):
    from nmrm_ros.rl import SplitLRSAC

    torch.set_num_threads(1)
    model = SplitLRSAC("MlpPolicy", Line(), seed=0, device="cpu", learning_starts=50, batch_size=32,
                       gamma=0.9, ent_coef=0.2, policy_kwargs={"net_arch": [16, 16]})
    model.learn(total_timesteps=60)
    bound = model.value_bound
    assert bound is not None and bound.reward_high <= 1.0
    assert bound.high == pytest.approx((bound.reward_high + 0.2 * np.log(2.0)) / 0.1)
    with torch.no_grad():  # target critics whose values ran away
        for q in model.policy.critic_target.q_networks:
            q[-1].bias.fill_(1e4)
    before = model.targets_clipped
    model.train(gradient_steps=1, batch_size=32)
    assert model.targets_clipped > before
    with torch.no_grad():
        qs = model.critic_target(torch.zeros(4, 1), torch.zeros(4, 1))
    assert all(float(q.max()) <= bound.high + 1e-4 for q in qs)
    # saved and loaded as SB3's SAC, as `nmrm rl evaluate` loads it
    from stable_baselines3 import SAC

    path = tmp_path / "p.zip"
    model.save(path)
    SAC.load(path, device="cpu").predict(np.zeros(1, np.float32), deterministic=True)


@pytest.mark.parametrize("line, message", [
    ("keep_every: -1", "keep_every in .* must be a whole number of episodes >= 0"),
    ("keep_every: 2.5", "keep_every in .* must be a whole number"),
    ("bound_values: maybe", "bound_values in .* must be true or false"),
    ("catch_up_steps: -5", "catch_up_steps in .* must be a whole number of gradient steps >= 0"),
    ("catch_up_steps: 1.0e+4", "catch_up_steps in .* must be a whole number"),
])
def test_nonsense_trust_settings_are_one_line_errors(tmp_path, line, message):
    from nmrm_ros.rl import load_rl_config

    config = tmp_path / "rl.yaml"
    config.write_text(f"dqn: {{learning_rate: 1.0e-3, {line}}}\n")
    with pytest.raises(ValueError, match=message):
        load_rl_config("dqn", config)
    config.write_text("dqn: {learning_rate: 1.0e-3}\n")  # a config written before them: the defaults
    from nmrm_ros.rl.config import trust_settings

    assert trust_settings(load_rl_config("dqn", config)) == {"bound_values": True, "keep_every": 20,
                                                             "catch_up_steps": 10000}
