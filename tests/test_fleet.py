"""A fleet of two robots feeding one learner: real node processes, under `ros2 launch` (one launch
per robot and one for the learner, as on several machines) and under `nmrm fleet`."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from nmrm_ros.testing.graph import executable, finish
from nmrm_ros.bags import iter_decoded, load_bag_dataset

REPO = Path(__file__).resolve().parents[1]

LAUNCH_DIR = REPO / "launch_scripts"
ROS2 = Path(os.environ.get("NMRM_VENV", REPO / ".venv")) / "bin" / "ros2"


def _popen(cmd: list) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def _steps_per_robot(bag: Path) -> dict:
    """robot namespace -> the augmented states the learner acted on (non-final RewardSteps), in order."""
    steps: dict = {}
    for topic, _, _, msg in iter_decoded(bag):
        if topic.endswith("/nmrm/reward_step") and not (msg.terminated or msg.truncated):
            steps.setdefault(topic.split("/")[1], []).append(np.asarray(msg.augmented_state, np.float32))
    return {k: np.stack(v) for k, v in steps.items()}


@pytest.mark.skipif(not ROS2.exists(), reason=f"real ROS 2 CLI not installed ({ROS2} missing)")
def test_fleet_of_two_feeds_one_learner_under_ros2_launch(ros_domain, tmp_path):
    """Two robots (2 episodes each) and the learner (4 fleet episodes): every transition of both
    robots is in the learner's replay buffer, robot j's in the vectorised env's column j, in the
    order its graph produced them; the fleet's bag keys episodes by robot."""
    out = tmp_path / "fleet"
    robots = [_popen([str(ROS2), "launch", str(LAUNCH_DIR / "fleet_robot.launch.yaml"), f"namespace:=robot{i + 1}",
                      f"seed:={i * 100000}", "episodes:=2"]) for i in range(2)]
    learner = _popen([str(ROS2), "launch", str(LAUNCH_DIR / "fleet_learner.launch.yaml"),
                      "robots:=[/robot1, /robot2]", "episodes:=4", "learning_starts:=50",
                      "save_replay_buffer:=true", f"out:={out}"])
    results = [finish(p, timeout=180) for p in (*robots, learner)]
    for code, text in results:
        assert code == 0 and "process has died" not in text, text
    assert "learner finished 4 episodes" in results[2][1], results[2][1]
    meta = json.loads((out / "policy" / "agent.json").read_text())
    assert meta["robots"] == ["/robot1", "/robot2"] and meta["episodes_done"] == 4

    from stable_baselines3.common.save_util import load_from_pkl

    buffer = load_from_pkl(out / "policy" / "replay_buffer.pkl")
    assert buffer.n_envs == 2 and buffer.pos == 200  # 200 fleet steps, 2 transitions each
    steps = _steps_per_robot(out / "bag")
    assert sorted(steps) == ["robot1", "robot2"]
    for j, robot in enumerate(("robot1", "robot2")):
        assert steps[robot].shape[0] == 200
        np.testing.assert_array_equal(buffer.observations[:200, j], steps[robot], err_msg=robot)
    assert not np.array_equal(steps["robot1"], steps["robot2"])  # different seeds, different episodes
    ds, report = load_bag_dataset([out / "bag"])
    assert len(ds) == 4, report


def test_nmrm_fleet_learns_from_two_robots(ros_domain, tmp_path):
    """`nmrm fleet --robots 2`: one launcher, eight nodes, every fleet episode on the curve with
    its robot's oracle label."""
    out = tmp_path / "fleet"
    code, text = finish(_popen([executable("nmrm"), "fleet", "--robots", "2", "--episodes", "2",
                                "--learning-starts", "50", "--out", str(out)]), timeout=180)
    assert code == 0, text
    assert "all 8 node(s) exited cleanly" in text and "learner finished 4 episodes" in text, text
    rows = (out / "policy" / "curve.csv").read_text().splitlines()[1:]
    assert len(rows) == 4 and all(r.split(",")[1] != "nan" for r in rows), rows
    ds, report = load_bag_dataset([out / "bag"])
    assert len(ds) == 4, report
