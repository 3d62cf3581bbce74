"""The node graph over real topics, each node its own process (each test on its own domain)."""

import re
import sys
from collections import Counter

import numpy as np
import pytest

from nmrm_ros.testing.graph import PROBE_EPISODE, Capture, episodes_of, finish, launch, start
from nmrm_msgs.msg import EnvObservation
from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import load_checkpoint, load_train_config
from nmrm_ros.mil.online import batched_reference
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.oracles import make_oracle
from nmrm_ros.ros.topics import OBSERVATION
from nmrm_ros.tasks.frames import parse_frame_id

EPISODES = 3


@pytest.fixture
def capture(ros_domain):
    cap = Capture()
    yield cap
    cap.close()


@pytest.fixture
def graph_capture(ros_domain):
    """A capture for `run_graph`: it subscribes to observations once it has matched the graph."""
    cap = Capture(deferred=("observation", "observation_image"))
    yield cap
    cap.close()


@pytest.fixture(scope="module")
def key_checkpoint(tmp_path_factory):
    """A small CSC model trained for a few epochs on Key trajectories."""
    ds = generate_screened("key", 300, seed=0)
    cfg = load_train_config("key", max_epochs=3)
    path = tmp_path_factory.mktemp("ckpt") / "key_csc"
    run = fit(ds, "csc_lstm", cfg, out=path, progress=False)
    return run.checkpoint


def run_graph(capture, *arguments):
    """Launch the graph with one extra subscriber (the capture) and wait for it to finish.

    env_sim waits for 3 observation subscribers: labeller, reward model and the capture, which
    subscribes only once it has matched the agent's, labeller's and reward model's publishers
    (then 1 s more, for those publishers to match the capture's subscriptions in turn).
    """
    proc = launch(*arguments, f"episodes:={EPISODES}", "wait_for_subscribers:=3", "start_delay:=1.0")
    try:
        capture.subscribe_when_matched({"action": 1, "reward_step": 1, "label": 1, "oracle_step": 1})
    except AssertionError:
        proc.kill()
        raise AssertionError(f"{sys.exc_info()[1]}\n{finish(proc)[1]}") from None
    capture.spin_until(lambda: proc.poll() is not None, 90)
    code, out = finish(proc, timeout=30)
    capture.spin_for(0.3)
    assert code == 0, out
    assert "all 4 node(s) exited cleanly" in out
    return out


def check_lockstep(capture, task="key"):
    eps = episodes_of(capture.msgs["observation"])
    assert sorted(eps) == list(range(EPISODES))
    for e, (_, steps, flags) in eps.items():
        assert steps == list(range(101)), f"episode {e}: steps {steps[:5]}..."
        assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])
    actions = Counter((m.episode, m.step) for m in capture.msgs["action"])
    assert set(actions) == {(e, t) for e in range(EPISODES) for t in range(100)}
    assert set(actions.values()) == {1}  # every step answered exactly once
    steps = Counter((m.episode, m.step) for m in capture.msgs["reward_step"])
    assert set(steps) == {(e, t) for e in range(EPISODES) for t in range(101)} and set(steps.values()) == {1}
    return eps


def test_graph_oracle_mode_and_labeller(graph_capture):
    capture = graph_capture
    out = run_graph(capture, "mode:=oracle", "task:=key")
    eps = check_lockstep(capture)
    oracle = make_oracle("key")
    labels = {m.episode: m for m in capture.msgs["label"]}
    assert sorted(labels) == list(range(EPISODES))
    for e, (states, _, _) in eps.items():
        truth = oracle.label(states[None, :100])
        # the labeller's return equals the oracle's return computed offline from the observations
        assert labels[e].return_value == pytest.approx(truth.returns[0], abs=1e-9)
        assert labels[e].length == 100 and labels[e].labeller == "oracle/key" and labels[e].task == "key"
        rs = sorted((m for m in capture.msgs["reward_step"] if m.episode == e), key=lambda m: m.step)
        np.testing.assert_allclose([m.reward for m in rs[:100]], truth.rewards[0], atol=1e-6)
        np.testing.assert_allclose([m.hidden[0] for m in rs[:100]], truth.hidden[0, :, 0], atol=1e-6)
        assert all(m.source == "oracle" for m in rs)
        assert list(rs[5].augmented_state) == list(rs[5].state) + list(rs[5].hidden)
        os_ = sorted((m for m in capture.msgs["oracle_step"] if m.episode == e), key=lambda m: m.step)
        np.testing.assert_allclose([m.reward for m in os_], truth.rewards[0], atol=1e-6)
    assert "labelled 3 episode(s), 0 broken" in out


def test_a_pixel_task_on_the_graph_is_labelled_from_its_privileged_state(graph_capture):
    """key_pixels: env_sim publishes the image (on nmrm/observation_image, the observation's state
    empty) and the position as the privileged state; the labeller and the reward model (oracle
    mode) step the oracle with the position."""
    capture = graph_capture
    run_graph(capture, "mode:=oracle", "task:=key_pixels")
    oracle = make_oracle("key")
    labels = {m.episode: m for m in capture.msgs["label"]}
    assert sorted(labels) == list(range(EPISODES))
    for e in range(EPISODES):
        obs = sorted((m for m in capture.msgs["observation"] if m.episode == e), key=lambda m: m.step)
        assert len(obs[0].state) == 0 and len(obs[0].privileged) == 2
        positions = np.array([m.privileged for m in obs[:100]], dtype=np.float32)
        truth = oracle.label(positions[None])
        assert labels[e].return_value == pytest.approx(truth.returns[0], abs=1e-9)
        rs = sorted((m for m in capture.msgs["reward_step"] if m.episode == e), key=lambda m: m.step)
        np.testing.assert_allclose([m.reward for m in rs[:100]], truth.rewards[0], atol=1e-6)


def test_graph_model_mode_equals_batched_forward(graph_capture, key_checkpoint):
    capture = graph_capture
    run_graph(capture, "mode:=model", f"checkpoint:={key_checkpoint}", "task:=key")
    eps = check_lockstep(capture)
    model, _ = load_checkpoint(key_checkpoint)
    for e, (states, _, _) in eps.items():
        rewards, hidden = batched_reference(model, states)  # includes the final observation
        rs = sorted((m for m in capture.msgs["reward_step"] if m.episode == e), key=lambda m: m.step)
        np.testing.assert_allclose([m.reward for m in rs], rewards, atol=1e-4)
        np.testing.assert_allclose([list(m.hidden) for m in rs], hidden, atol=1e-5)
        assert rs[0].source == "key_csc"


@pytest.fixture(scope="module")
def pixel_checkpoint(tmp_path_factory):
    """A small key_pixels CSC ensemble (2 members, 1 epoch): a model that reads the 32 x 32 image."""
    from nmrm_ros.tasks.pixel_navigation import pixel_dataset

    px = pixel_dataset(generate_screened("key", 40, seed=5), "key_pixels")
    cfg = load_train_config("key_pixels", max_epochs=1, threads=1)
    return fit(px, "csc_lstm", cfg, members=2, out=tmp_path_factory.mktemp("px") / "key_pixels_csc",
               progress=False).checkpoint


def test_a_pixel_model_serves_on_the_graph_what_it_serves_an_agents_wrapper(graph_capture, pixel_checkpoint):
    """key_pixels in model mode: each episode's RewardSteps (reward, served state, augmented state
    [image, served]) equal what the agents' wrapper serves on the same episode (seed e, the same
    actions), and the batched forward of the observed images."""
    from nmrm_ros.rl import EpisodeSeeds, RewardModelWrapper
    from nmrm_ros.tasks import make_env

    capture = graph_capture
    run_graph(capture, "mode:=model", f"checkpoint:={pixel_checkpoint}", "task:=key_pixels")
    # the pixels travel as one PNG a step on nmrm/observation_image, not as floats in the messages
    images = {parse_frame_id(m.header.frame_id): m for m in capture.msgs["observation_image"]}
    assert set(images) == {(m.episode, m.step) for m in capture.msgs["observation"]}
    for m in capture.msgs["observation"]:
        image = images[(m.episode, m.step)]
        assert image.format == "png" and image.header.stamp == m.header.stamp
    assert all(len(m.state) == 0 for m in capture.msgs["observation"] + capture.msgs["reward_step"])
    assert all(len(m.augmented_state) == len(m.hidden) for m in capture.msgs["reward_step"])
    capture.msgs["observation"] = capture.joined("observation", "key_pixels")
    capture.msgs["reward_step"] = capture.joined("reward_step", "key_pixels")
    eps = check_lockstep(capture)
    model, meta = load_checkpoint(pixel_checkpoint, task="key_pixels")
    wrapper = RewardModelWrapper(EpisodeSeeds(make_env("key_pixels"), 0), pixel_checkpoint, task="key_pixels")
    for e, (states, _, _) in eps.items():
        assert states.shape == (101, 32 * 32 * 3)
        rs = sorted((m for m in capture.msgs["reward_step"] if m.episode == e), key=lambda m: m.step)
        rewards, served = batched_reference(model, states, meta.served_state)
        np.testing.assert_allclose([m.reward for m in rs], rewards, atol=1e-4)
        np.testing.assert_allclose([list(m.hidden) for m in rs], served, atol=1e-5)
        actions = {m.step: m.action for m in capture.msgs["action"] if m.episode == e}
        obs, _ = wrapper.reset(seed=e)
        np.testing.assert_allclose(obs, rs[0].augmented_state, atol=1e-5)
        for t in range(100):
            obs, reward, *_ = wrapper.step(int(actions[t][0]))
            assert reward == pytest.approx(rs[t].reward, abs=1e-4)
            np.testing.assert_allclose(obs, rs[t + 1].augmented_state, atol=1e-5)


def test_bad_observations_are_dropped_and_counted(capture):
    """Wrong state size, NaN and a skipped step break the episode in the reward model and the
    labeller: logged, counted, nothing published for it; a good episode afterwards works."""
    rm = start("reward_model", mode="oracle", task="key")
    lab = start("labeller_oracle", task="key")
    pub = capture.publisher(EnvObservation, OBSERVATION)
    def obs(e, t, state, truncated=False):
        return EnvObservation(task="key", episode=e, step=t, state=state, truncated=truncated)
    def probe(e):
        pub.publish(obs(e, 0, [0.5, 0.5]))
        pub.publish(obs(e, 1, [0.5, 0.5], truncated=True))
    capture.handshake(probe, ("reward_step", "label"))
    sent = [obs(0, 0, [0.5, 0.5]), obs(0, 1, [0.5, 0.5, 0.5]),                  # wrong size
            obs(1, 0, [0.5, 0.5]), obs(1, 1, [float("nan"), 0.5]),             # NaN
            obs(2, 0, [0.5, 0.5]), obs(2, 2, [0.5, 0.6]),                      # step 1 missing
            obs(3, 0, [0.5, 0.2]), obs(3, 1, [0.5, 0.8]), obs(3, 1, [0.5, 0.8]),  # duplicate: fine
            obs(3, 2, [0.5, 0.8], truncated=True)]
    for m in sent:
        pub.publish(m)
    assert capture.spin_until(lambda: any(m.episode == 3 for m in capture.msgs["label"]), 20)
    capture.spin_for(0.5)
    for p in (rm, lab):
        p.send_signal(2)
    code_rm, out_rm = finish(rm)
    code_lab, out_lab = finish(lab)
    assert code_rm == 0 and code_lab == 0
    # only episode 3 was labelled: key at t = 0, treasure at t = 1 -> return 1
    labels = [(m.episode, m.return_value, m.length) for m in capture.msgs["label"] if m.episode < PROBE_EPISODE]
    assert labels == [(3, 1.0, 2)]
    published = Counter((m.episode, m.step) for m in capture.msgs["reward_step"] if m.episode < PROBE_EPISODE)
    assert set(published) == {(0, 0), (1, 0), (2, 0), (3, 0), (3, 1), (3, 2)}
    assert published[(3, 1)] == 2  # the duplicate got the same answer again
    assert "size 3, expected 2" in out_rm and "NaN" in out_rm and "out of order" in out_rm
    # a probe the node saw only in part (before it matched the capture) is broken too
    def broken_probes(out, pattern):
        return sum(int(e) >= PROBE_EPISODE for e in re.findall(pattern, out))
    rm_broken = 3 + broken_probes(out_rm, r"episode (\d+) broken at step")
    lab_broken = 3 + broken_probes(out_lab, r"episode (\d+) not labelled")
    assert f"{rm_broken} broken episode(s)" in out_rm, out_rm
    assert re.search(rf"labelled \d+ episode\(s\), {lab_broken} broken", out_lab), out_lab
    for e in range(3):
        assert f"episode {e} not labelled" in out_lab and f"episode {e} broken at step" in out_rm


def test_reward_model_serves_an_ensemble(capture, tmp_path):
    """An ensemble checkpoint: RewardStep carries the members' mean reward, their spread
    (reward_std, return_std) and the serving member's hidden state, as the online ensemble
    computes them."""
    from nmrm_ros.mil import OnlineRewardModel
    from nmrm_ros.mil.pipeline import fit

    ds = generate_screened("key", 200, seed=1)
    run = fit(ds, "csc_lstm", load_train_config("key", max_epochs=1),
                             members=3, out=tmp_path / "ens", progress=False)
    rm = start("reward_model", mode="model", checkpoint=str(run.checkpoint), task="key")
    pub = capture.publisher(EnvObservation, OBSERVATION)
    capture.handshake(lambda e: pub.publish(EnvObservation(task="key", episode=e, step=0, state=[0.5, 0.5])),
                      ("reward_step",))
    states = ds.states[0, :6].astype(float)
    for t, s in enumerate(states):
        pub.publish(EnvObservation(task="key", episode=0, step=t, state=list(s), truncated=t == 5))
    def served():
        return sorted((m for m in capture.msgs["reward_step"] if m.episode == 0), key=lambda m: m.step)
    assert capture.spin_until(lambda: len(served()) >= 6, 20)
    rm.send_signal(2)
    code, out = finish(rm)
    assert code == 0, out
    model, _ = load_checkpoint(run.checkpoint)
    online = OnlineRewardModel(model)
    for m, s in zip(served(), states):
        reward, hidden = online.step(s)
        assert m.reward == pytest.approx(reward, abs=1e-5)
        assert m.reward_std == pytest.approx(online.reward_std, abs=1e-5) and m.reward_std > 0
        assert m.return_std == pytest.approx(online.return_std, abs=1e-5)
        np.testing.assert_allclose(m.hidden, hidden, atol=1e-6)


@pytest.mark.parametrize("node,params,message", [
    ("env_sim", {"task": "maze"}, "unknown task 'maze'"),
    ("labeller_oracle", {"task": "maze"}, "unknown task 'maze'"),
    ("reward_model", {"mode": "model", "checkpoint": "/nonexistent/ckpt"}, "checkpoint file missing"),
    ("reward_model", {"mode": "oracle"}, "needs the parameter task"),
    ("reward_model", {"mode": "model", "checkpoint": "/x", "served_state": "c"}, "served_state must be one of h_tanh_c, h_c, h"),
    ("agent", {"policy": "sb3", "policy_path": "/nonexistent.zip"}, "existing policy_path"),
    ("env_sim", {"task": "key", "render": True}, "task 'key' renders no frames"),
    ("env_sim", {"task": "gym:CartPole-v1", "render": True, "render_format": "gif"}, "render_format must be one of jpeg, png"),
    ("env_sim", {"task": "gym:CartPole-v1", "render": True, "render_quality": 99}, "render_quality must be in 1..95"),
    ("labeller_oracle", {"task": "gym:CartPole-v1"}, "has no oracle of ours: give your own"),
    ("labeller_oracle", {"task": "gym:CartPole-v1", "oracle": "/nope.py:f"}, "oracle '/nope.py:f': no file /nope.py"),
    ("reward_model", {"mode": "oracle", "task": "key", "oracle": "os:sep"}, "is a str, not a function"),
])
def test_bad_configuration_exits_with_message(ros_domain, node, params, message):
    code, out = finish(start(node, **params), timeout=30)
    assert code == 2 and message in out, out


def test_mismatched_checkpoint_is_refused(ros_domain, key_checkpoint):
    code, out = finish(start("reward_model", mode="model", checkpoint=key_checkpoint, task="timer"), 30)
    assert code == 2 and "trained on task 'key', not 'timer'" in out


def test_launch_reports_a_dead_node(ros_domain):
    code, out = finish(launch("mode:=model", "checkpoint:=/nonexistent", "episodes:=1"), timeout=60)
    assert code == 1
    assert "node 'reward_model' died with exit code 2" in out and "checkpoint file missing" in out


def test_env_sim_drops_bad_actions(capture):
    """Stale, malformed and NaN actions are dropped with a counted warning, never stepped."""
    from nmrm_msgs.msg import AgentAction
    from nmrm_ros.ros.topics import ACTION

    env = start("env_sim", task="key", episodes=1, wait_for_subscribers=1, action_timeout=30.0)
    pub = capture.publisher(AgentAction, ACTION)
    assert capture.spin_until(lambda: len(capture.msgs["observation"]) >= 1, 30)
    for bad in (AgentAction(episode=0, step=5, action=[1.0]),     # future step
                AgentAction(episode=0, step=0, action=[7.0]),     # not an action index
                AgentAction(episode=0, step=0, action=[1.0, 2.0]),  # wrong size
                AgentAction(episode=0, step=0, action=[float("nan")])):
        pub.publish(bad)
    capture.spin_for(0.5)
    assert len(capture.msgs["observation"]) == 1  # nothing was stepped
    for t in range(100):
        pub.publish(AgentAction(episode=0, step=t, action=[1.0]))
        assert capture.spin_until(lambda n=t + 2: len(capture.msgs["observation"]) >= n, 10)
    code, out = finish(env)
    assert code == 0 and "4 action(s) dropped" in out
    states = np.array([list(m.state) for m in capture.msgs["observation"]])
    assert states.shape == (101, 2) and capture.msgs["observation"][-1].truncated


def test_agent_runs_a_saved_sb3_policy(capture, tmp_path):
    """The agent node loads a stable-baselines3 DQN saved for the augmented Key state (2 + 1) and
    answers each RewardStep with the policy's deterministic action."""
    import gymnasium as gym
    from stable_baselines3 import DQN

    from nmrm_msgs.msg import RewardStep
    from nmrm_ros.ros.topics import REWARD_STEP

    class AugmentedKeySpaces(gym.Env):  # only gives DQN the spaces of [x, y, h]
        observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
        action_space = gym.spaces.Discrete(5)

    policy = DQN("MlpPolicy", AugmentedKeySpaces(), policy_kwargs={"net_arch": [16]}, seed=0)
    policy.save(tmp_path / "dqn.zip")
    agent = start("agent", task="key", policy="sb3", policy_path=str(tmp_path / "dqn.zip"))
    pub = capture.publisher(RewardStep, REWARD_STEP)
    capture.handshake(lambda e: pub.publish(RewardStep(episode=e, step=0, augmented_state=[0.5, 0.5, 0.0])),
                      ("action",))
    rng = np.random.default_rng(0)
    states = rng.uniform(0, 1, (20, 3)).astype(np.float32)
    for t, s in enumerate(states):
        pub.publish(RewardStep(episode=0, step=t, augmented_state=s.tolist()))
    pub.publish(RewardStep(episode=0, step=20, augmented_state=[0.0, 0.0, 0.0], truncated=True))
    assert capture.spin_until(lambda: sum(m.episode == 0 for m in capture.msgs["action"]) >= 20, 30)
    capture.spin_for(0.3)
    agent.send_signal(2)
    code, out = finish(agent)
    assert code == 0, out
    got = {(m.episode, m.step): m.action[0] for m in capture.msgs["action"] if m.episode == 0}
    assert len(got) == 20  # none for the final step
    expected, _ = policy.predict(states, deterministic=True)
    assert [got[(0, t)] for t in range(20)] == [float(a) for a in expected]


def test_a_pixel_bag_is_served_again_with_its_images(ros_domain, tmp_path, pixel_checkpoint):
    """serve_replay.launch.yaml, which names only /nmrm/observation, on a bag of an image task: the
    observation images go with the observations (replay and recorder both take them), and the
    recorded rewards are the model's batched forward of the images."""
    import subprocess

    from nmrm_ros.bags.episodes import load_bag_dataset, write_dataset_bag
    from nmrm_ros.bags.reader import bag_summary, iter_decoded
    from nmrm_ros.ros.ament_paths import require_share_dir
    from nmrm_ros.testing.graph import executable
    from nmrm_ros.tasks.pixel_navigation import pixel_dataset

    ds = pixel_dataset(generate_screened("key", 2, seed=7, pool_size=40), "key_pixels")
    bag = write_dataset_bag(ds, tmp_path / "pixels")
    served = tmp_path / "served"
    launch_file = require_share_dir("nmrm_ros") / "launch_scripts" / "serve_replay.launch.yaml"
    proc = subprocess.Popen([executable("nmrm"), "launch", str(launch_file), f"bag:={bag}",
                             f"checkpoint:={pixel_checkpoint}", f"out:={served}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    code, out = finish(proc, 120)
    assert code == 0, out
    steps = int((ds.lengths + 1).sum())
    summary = bag_summary(served)
    assert [summary[t][1] for t in ("/nmrm/observation", "/nmrm/observation_image", "/nmrm/reward_step")] == \
        [steps] * 3, summary
    back, _ = load_bag_dataset([bag])
    model, meta = load_checkpoint(pixel_checkpoint, task="key_pixels")
    rewards = {(m.episode, m.step): m.reward for _, t, _, m in iter_decoded(served) if t.endswith("RewardStep")}
    for i in range(len(ds)):
        n = int(ds.lengths[i])
        states = np.concatenate([back.states[i, :n], back.final_states[i][None]])
        expected, _ = batched_reference(model, states, meta.served_state)
        np.testing.assert_allclose([rewards[(i, t)] for t in range(n + 1)], expected, atol=1e-4)
