"""Learning through the ROS graph (agent policy:=learn): real node processes over real topics."""

from __future__ import annotations

import json
from pathlib import Path
import signal
import subprocess
import time

import numpy as np
import pytest
import torch

from nmrm_ros.testing.graph import executable, finish, start
from nmrm_ros.bags import load_bag_dataset
from nmrm_ros.rl import train_agent

REPO = Path(__file__).resolve().parents[1]

LEARN_LAUNCH = REPO / "launch_scripts" / "learn.launch.yaml"


@pytest.fixture(scope="module")
def key_checkpoint(small_key_checkpoint):
    return small_key_checkpoint


def test_graph_learner_sees_the_same_transitions_as_the_wrapper(ros_domain, tmp_path, key_checkpoint):
    """env_sim -> reward_model (a CSC checkpoint) -> agent learning, seed 3, 2 episodes, learning
    from step 50: the agent's replay buffer equals the one of the same run through the gymnasium
    wrapper (observations [s_t, h'_{t+1}], actions, rewards r'_t, next observations, dones), so the
    wrapper's rewards are the reward_model node's and learning is the same with or without ROS
    (in SB3's order: overlap_training false). With the oracle labeller beside it, the agent ends
    checking its model against the labels as `nmrm rl train` does against the oracle: the same
    figures."""
    out = tmp_path / "policy"
    procs = [
        start("reward_model", mode="model", checkpoint=key_checkpoint, task="key", exit_with_upstream=True),
        start("agent", task="key", policy="learn", seed=3, episodes=2, learning_starts=50, out=out,
              save_replay_buffer=True, log_every=1, exit_with_upstream=True, overlap_training=False,
              checkpoint=key_checkpoint),
        start("labeller_oracle", task="key", exit_with_upstream=True),
        start("env_sim", task="key", seed=3, episodes=2, wait_for_nodes="[reward_model, labeller_oracle]"),
    ]
    outputs = [finish(p, timeout=120) for p in procs]
    for code, text in outputs:
        assert code == 0, text
    assert "learner finished 2 episodes" in outputs[1][1]
    meta = json.loads((out / "agent.json").read_text())
    assert meta["episodes_done"] == 2 and meta["reward"] == "model"
    assert "the model on the agent's last 2 episodes: paid" in outputs[1][1] and "by the labeller" in outputs[1][1]

    from stable_baselines3.common.save_util import load_from_pkl

    graph = load_from_pkl(out / "replay_buffer.pkl")
    torch.set_num_threads(1)
    run = train_agent("key", "model", checkpoint=key_checkpoint, episodes=2, seed=3, progress=False,
                      learning_starts=50)
    local = run.model.replay_buffer
    assert graph.pos == local.pos == 200
    for key in ("episodes", "learnt", "judged", "rmse", "passed"):
        assert meta["model_check"][key] == pytest.approx(run.model_check.to_dict()[key], rel=1e-6), key
    for field in ("observations", "actions", "rewards", "next_observations", "dones", "timeouts"):
        np.testing.assert_array_equal(getattr(graph, field)[:200], getattr(local, field)[:200], err_msg=field)
    # and the learnt weights after 150 gradient steps
    from stable_baselines3 import DQN

    graph_model = DQN.load(out / "policy.zip", device="cpu")
    for k, v in run.model.policy.state_dict().items():
        torch.testing.assert_close(graph_model.policy.state_dict()[k], v, msg=k)


def learn_launch(tmp_path, *arguments):
    return subprocess.Popen([executable("nmrm"), "launch", str(LEARN_LAUNCH), f"out:={tmp_path / 'learn'}",
                             *arguments], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_learn_launch_file_learns_records_and_saves(ros_domain, tmp_path):
    code, out = finish(learn_launch(tmp_path, "task:=key", "episodes:=3", "mode:=oracle", "save_every:=2",
                                    "learning_starts:=100"), timeout=180)
    assert code == 0, out
    assert "all 5 node(s) exited cleanly" in out
    assert "saved " in out and "after 2 episode(s)" in out and "after 3 episode(s)" in out
    policy = tmp_path / "learn" / "policy"
    rows = (policy / "curve.csv").read_text().splitlines()
    assert len(rows) == 4
    # the oracle labeller's returns reach the curve (episode ids 0..2)
    assert [r.split(",")[0] for r in rows[1:]] == ["0", "1", "2"]
    assert all(r.split(",")[1] != "nan" for r in rows[1:])
    ds, report = load_bag_dataset([tmp_path / "learn" / "bag"])
    assert len(ds) == 3, report


def test_sigint_saves_the_policy(ros_domain, tmp_path):
    proc = learn_launch(tmp_path, "task:=key", "episodes:=1000", "mode:=oracle", "save_every:=0")
    deadline = time.monotonic() + 90
    seen = []
    for line in proc.stdout:  # wait until the agent has started learning, then one second more
        seen.append(line)
        if "[agent]" in line and "learning dqn" in line:
            break
        assert time.monotonic() < deadline, "".join(seen)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    code, out = finish(proc, timeout=60)
    out = "".join(seen) + out
    policy = tmp_path / "learn" / "policy"
    assert (policy / "policy.zip").stat().st_size > 0, out
    meta = json.loads((policy / "agent.json").read_text())
    assert meta["outcome"] == "stopped by shutdown", out
    assert "learner stopped by shutdown" in out


def test_loop_launch_file_retrains_swaps_and_relabels_the_agents_replay_buffer(ros_domain, tmp_path, key_checkpoint):
    """loop.launch.yaml: the oracle labels the learning agent's episodes, the trainer retrains every
    10 labels and swaps each version in; the agent relabels its replay buffer with each version once
    it is served. At exit every stored transition of an episode served by the last version the
    agent relabelled with, or by an earlier one, is exactly what that last version gives."""
    import copy

    from nmrm_ros.bags.reader import iter_decoded
    from nmrm_ros.mil import OnlineRewardModel, load_checkpoint
    from nmrm_ros.rl.replay_relabel import relabel_replay_buffer
    from stable_baselines3.common.save_util import load_from_pkl

    import yaml

    # The catch-up after each swap (config/rl.yaml: 10000 gradient steps, ~20 s each of the 5 swaps
    # here) is the loop's own test's (test_reward_model_loop.py); this one checks the relabelling:
    # 500 steps, through the agent's rl_config parameter.
    rl = yaml.safe_load((REPO / "config" / "rl.yaml").read_text())
    rl["dqn"]["catch_up_steps"] = 500
    (tmp_path / "rl.yaml").write_text(yaml.safe_dump(rl))
    params = yaml.safe_load((REPO / "config" / "graph.yaml").read_text())
    params["/**/agent"]["ros__parameters"]["rl_config"] = str(tmp_path / "rl.yaml")
    (tmp_path / "graph.yaml").write_text(yaml.safe_dump(params))
    out = tmp_path / "loop"
    code, text = finish(subprocess.Popen(
        [executable("nmrm"), "launch", str(REPO / "launch_scripts" / "loop.launch.yaml"), "task:=key",
         f"checkpoint:={key_checkpoint}", "episodes:=60", "labels_per_round:=10", "members:=1", "max_epochs:=2",
         "save_replay_buffer:=true", f"out:={out}", f"params:={tmp_path / 'graph.yaml'}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True), timeout=300)
    assert code == 0, text
    relabelled = [line.split("relabelled with ")[1].split(":")[0] for line in text.splitlines()
                  if "replay buffer relabelled with" in line]
    assert relabelled, text
    assert "up to 500 catch-up gradient steps follow" in text, text  # the params file reached the agent
    assert len((out / "agent" / "curve.csv").read_text().splitlines()) == 61
    served = {}  # episode id -> the model that served it
    for _, _, _, msg in iter_decoded(out / "bag", ["/nmrm/reward_step"]):
        served.setdefault(msg.episode, msg.source)
    assert len(served) == 60 and relabelled[-1] in served.values(), served
    first_after = min([e for e, name in served.items() if name > relabelled[-1]], default=60)

    saved = load_from_pkl(out / "agent" / "replay_buffer.pkl")
    assert saved.pos == 6000
    model, meta = load_checkpoint(out / "checkpoints" / relabelled[-1])
    redone = copy.deepcopy(saved)
    relabel_replay_buffer(redone, OnlineRewardModel(model, served=meta.served_state), 2)
    upto = first_after * 100  # episodes are 100 steps: transitions of episodes served up to the last relabel
    np.testing.assert_allclose(saved.rewards[:upto], redone.rewards[:upto], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(saved.observations[:upto], redone.observations[:upto], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(saved.next_observations[:upto], redone.next_observations[:upto], rtol=1e-5, atol=1e-6)
