"""Several graphs at once: two robots in their own namespaces, one recorder, training from its bag."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from nmrm_ros.testing.graph import executable, finish, start
from nmrm_ros.bags import bag_summary, load_bag_dataset
from nmrm_ros.bags.reader import iter_decoded

REPO = Path(__file__).resolve().parents[1]
GRAPH = REPO / "launch_scripts" / "graph.launch.yaml"
ROS2 = Path(os.environ.get("NMRM_VENV", REPO / ".venv")) / "bin" / "ros2"
EPISODES = 5


def _launch_robot(namespace: str, seed: int, use_ros2: bool) -> subprocess.Popen:
    tool = [str(ROS2), "launch"] if use_ros2 else [executable("nmrm"), "launch"]
    # env_sim waits for 3 observation subscribers: labeller, reward model and the recorder
    return subprocess.Popen([*tool, str(GRAPH), f"namespace:={namespace}", f"episodes:={EPISODES}",
                             f"seed:={seed}", "wait_for_subscribers:=3", "start_delay:=1.0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def _wait_for_line(proc: subprocess.Popen, text: str, timeout: float = 60.0) -> str:
    seen, deadline = [], time.monotonic() + timeout
    for line in proc.stdout:
        seen.append(line)
        if text in line:
            return "".join(seen)
        assert time.monotonic() < deadline, "".join(seen)
    raise AssertionError("".join(seen))


def _why(bag, ns: str, summary: dict, outs: list, rec_out: str) -> str:
    """What a failed count needs to be explained: the observations recorded per episode (first and
    last step, count) and every process's log."""
    steps: dict = {}
    for _, _, _, msg in iter_decoded(bag, [f"{ns}/nmrm/observation"]):
        steps.setdefault(msg.episode, []).append(msg.step)
    per_episode = {e: (min(s), max(s), len(s)) for e, s in sorted(steps.items())}
    return (f"{ns}: observations per episode (first step, last step, count) {per_episode}\n"
            f"summary {summary}\n" + "\n".join(f"--- robot{i + 1}\n{o}" for i, o in enumerate(outs))
            + f"\n--- recorder\n{rec_out}")


def test_two_namespaced_graphs_one_recorder_and_training(ros_domain, tmp_path):
    """/robot1 (under the real `ros2 launch` when installed) and /robot2 (`nmrm launch`) run the
    same episode numbers 0..4 with different seeds; one recorder records both; the bag gives 10
    trajectories keyed by their namespace, and `nmrm train --bag` trains on them."""
    robots = [_launch_robot("robot1", 1, ROS2.exists()), _launch_robot("robot2", 2, False)]
    try:
        _run(robots, tmp_path)
    finally:  # a failed run must not leave the graphs running (ros2 launch's nodes are in its group)
        for r in robots:
            if r.poll() is None:
                os.killpg(r.pid, signal.SIGKILL)


def _run(robots, tmp_path):
    # the recorder starts once both graphs' nodes are up: a process that starts *before* the others
    # could take ~3.5 s to discover them without our discovery profile (README, "Discovery settings")
    logs = [_wait_for_line(r, "waiting for 3 subscriber(s)") for r in robots]
    bag = tmp_path / "two_robots"
    rec = start("recorder", output=str(bag), namespaces="[/robot1, /robot2]", exit_with_upstream=True)
    outs = []
    for r, head in zip(robots, logs):
        code, out = finish(r, 120)
        outs.append(head + out)
        assert code == 0, head + out
        assert f"done: {EPISODES} episodes" in out, head + out
    code, rec_out = finish(rec, 60)
    assert code == 0, rec_out
    summary = bag_summary(bag)
    for ns in ("/robot1", "/robot2"):
        counts = (summary[f"{ns}/nmrm/observation"][1], summary[f"{ns}/nmrm/trajectory_return"][1])
        assert counts == (EPISODES * 101, EPISODES), _why(bag, ns, summary, outs, rec_out)
    ds, report = load_bag_dataset([bag])
    assert len(ds) == 2 * EPISODES and report.episodes_used == 2 * EPISODES, report
    assert sorted(zip(ds.meta["sources"], ds.meta["episodes"])) == \
        [(ns, e) for ns in ("/robot1", "/robot2") for e in range(EPISODES)]
    # equal episode numbers, different robots: different trajectories
    first = [i for i, e in enumerate(ds.meta["episodes"]) if e == 0]
    assert len(first) == 2 and not (ds.states[first[0]] == ds.states[first[1]]).all()

    train = subprocess.run([executable("nmrm"), "train", "--bag", str(bag), "--epochs", "2",
                            "--out", str(tmp_path / "model")], capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stdout + train.stderr
    assert "10 episodes in the bags, 10 used" in train.stdout + train.stderr, train.stdout
    assert (tmp_path / "model.pt").is_file()
