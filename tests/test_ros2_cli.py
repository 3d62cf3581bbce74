"""Our package under the real ROS 2 Jazzy tools (`ros2 launch/run/param/topic`, launch_ros).

The tools come from ../shared/tools/ros2-cli-jazzy, installed into the venv by scripts/test.sh;
without that kit these tests skip, saying so. Every launch file runs to completion under
`ros2 launch` and under `nmrm launch` with the same arguments, and `nmrm launch` gives each
`name/value` parameter the type launch_ros gives it.
"""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from nmrm_ros.testing.graph import OutputLines, executable, finish
from nmrm_ros.bags import bag_summary, iter_decoded, load_bag_dataset

REPO = Path(__file__).resolve().parents[1]
LAUNCH_DIR = REPO / "launch_scripts"
ROS2 = Path(os.environ.get("NMRM_VENV", REPO / ".venv")) / "bin" / "ros2"
NODES = ("env_sim", "labeller_oracle", "labeller_web", "reward_model", "agent", "recorder", "replay",
         "trainer", "observation_bridge", "action_bridge", "fake_robot", "visualizer")

pytestmark = pytest.mark.skipif(
    not ROS2.exists(), reason=f"real ROS 2 CLI not installed ({ROS2} missing; scripts/test.sh installs it "
                              f"from ../shared/tools/ros2-cli-jazzy when that directory exists)")


def launcher(kind: str, file: str, *arguments: str) -> subprocess.Popen:
    tool = [str(ROS2), "launch"] if kind == "ros2" else [executable("nmrm"), "launch"]
    return subprocess.Popen([*tool, str(LAUNCH_DIR / file), *arguments], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def assert_nodes_exited_cleanly(kind: str, out: str, nodes: tuple) -> None:
    """`ros2 launch` exits 0 even when a node died: check each node's own exit in its log."""
    if kind == "ros2":
        for n in nodes:
            assert f"[INFO] [{n}-" in out and "process has finished cleanly" in out, out
        finished = [line for line in out.splitlines() if "process has finished cleanly" in line]
        assert len(finished) == len(nodes), out
        assert "process has died" not in out, out
    else:
        assert f"all {len(nodes)} node(s) exited cleanly" in out, out


@pytest.fixture(scope="module")
def key_checkpoint(small_key_checkpoint):
    return small_key_checkpoint


@pytest.mark.parametrize("kind", ["ros2", "nmrm"])
def test_every_launch_file_runs_to_completion(kind, ros_domain, tmp_path, key_checkpoint):
    """collect -> serve_replay on the collected bag -> graph (model mode) -> learn, each checked
    through the nodes' own exits and what they wrote."""
    bag = tmp_path / "collected"
    code, out = finish(launcher(kind, "collect.launch.yaml", "episodes:=3", f"out:={bag}"), 120)
    assert code == 0, out
    assert_nodes_exited_cleanly(kind, out, ("env_sim", "labeller_oracle", "agent", "recorder"))
    assert len(load_bag_dataset([bag])[0]) == 3

    served = tmp_path / "served"
    code, out = finish(launcher(kind, "serve_replay.launch.yaml", f"bag:={bag}",
                                f"checkpoint:={key_checkpoint}", f"out:={served}"), 120)
    assert code == 0, out
    assert_nodes_exited_cleanly(kind, out, ("replay", "reward_model", "recorder"))
    summary = bag_summary(served)
    assert summary["/nmrm/observation"][1] == 303 and summary["/nmrm/reward_step"][1] == 303, summary

    code, out = finish(launcher(kind, "graph.launch.yaml", "episodes:=2", "mode:=model",
                                f"checkpoint:={key_checkpoint}"), 120)
    assert code == 0, out
    assert_nodes_exited_cleanly(kind, out, ("env_sim", "labeller_oracle", "reward_model", "agent"))
    assert "done: 2 episodes, 200 steps" in out

    code, out = finish(launcher(kind, "learn.launch.yaml", "episodes:=2", "learning_starts:=50",
                                f"out:={tmp_path / 'learn'}"), 180)
    assert code == 0, out
    assert_nodes_exited_cleanly(kind, out, ("env_sim", "labeller_oracle", "reward_model", "agent", "recorder"))
    assert (tmp_path / "learn" / "policy" / "policy.zip").stat().st_size > 0


def _ros2(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(ROS2), *args], capture_output=True, text=True, timeout=timeout)


def test_ros2_param_and_topic_against_a_running_graph(ros_domain):
    """A graph running for ever under `ros2 launch`; `start_delay:=4` (an integer for a double)
    is accepted and reads back as a double."""
    proc = launcher("ros2", "graph.launch.yaml", "episodes:=0", "start_delay:=4")
    try:
        echo = _ros2("topic", "echo", "--once", "--no-daemon", "--spin-time", "5", "/nmrm/reward_step",
                     "nmrm_msgs/msg/RewardStep", timeout=90)
        assert echo.returncode == 0 and "augmented_state:" in echo.stdout, echo.stderr
        got = _ros2("param", "get", "--no-daemon", "--spin-time", "5", "/env_sim", "start_delay")
        assert got.stdout.strip() == "Double value is: 4.0", got.stdout + got.stderr
        got = _ros2("param", "get", "--no-daemon", "--spin-time", "5", "/reward_model", "mode")
        assert got.stdout.strip() == "String value is: oracle", got.stdout + got.stderr
        described = _ros2("param", "describe", "--no-daemon", "--spin-time", "5", "/env_sim", "episodes")
        assert "Min value: 0" in described.stdout, described.stdout + described.stderr
        nodes = _ros2("node", "list", "--no-daemon", "--spin-time", "5").stdout.split()
        assert {"/env_sim", "/labeller_oracle", "/reward_model", "/agent"} <= set(nodes), nodes
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        code, out = finish(proc, 60)
    assert code == 0, out
    assert "process has died" not in out and out.count("process has finished cleanly") == 4, out


def test_a_labelling_session_under_ros2_launch(ros_domain, tmp_path):
    """label.launch.yaml under `ros2 launch`: four episodes wait on the page; two labels posted to
    its API make the trainer write key_v001, which the reward model and the page's queue load;
    the labels are in the labels bag; Ctrl-C ends all six nodes cleanly."""
    from nmrm_ros.labelling.client import PageClient
    from nmrm_ros.mil import Run
    from nmrm_ros.mil.checkpoint import EnsembleInfo
    from nmrm_ros.mil.ensemble import init_ensemble
    from nmrm_ros.mil.models import model_config

    start = tmp_path / "key_start"
    Run.of(init_ensemble(model_config("csc_lstm", "key", 2), [0, 1]), "key",
           ensemble=EnsembleInfo(2, 0, seeds=[0, 1])).save(start)
    out_dir = tmp_path / "session"
    proc = launcher("ros2", "label.launch.yaml", f"checkpoint:={start}", "episodes:=4", "port:=0",
                    "retrain_every:=2", "members:=2", "max_epochs:=3", f"out:={out_dir}", "person:=carol")
    output = OutputLines(proc)
    wait_for = output.wait_for

    def api(path: str, body=None):
        client = PageClient(url)
        return client.get(path) if body is None else client.post(path, body)

    try:
        url = wait_for("labelling page: ").split("labelling page: ")[1].split()[0]
        # env_sim's "done" says all was published, not that the page has followed it all yet
        wait_for("waits for a label", count=4)
        queue = api("/api/queue")["episodes"]
        assert len(queue) == 4 and all(e["why"].startswith("models disagree") for e in queue), queue
        for e in queue[:2]:
            api("/api/label", {"episode": e["episode"], "return": 10.0})
        wait_for("reward_model loads")
        wait_for("labeller_web loads")
        assert (out_dir / "checkpoints" / "key_v001.pt").is_file()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            code = proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            code = proc.wait()
        output.reader.join(10)
    out = output.text()
    assert code == 0, out
    assert "process has died" not in out and out.count("process has finished cleanly") == 6, out
    labels = [m for bag in (out_dir / "labels").glob("person_*") for _, _, _, m in iter_decoded(bag)]
    assert sorted(m.episode for m in labels) == sorted(e["episode"] for e in queue[:2])
    assert {m.labeller for m in labels} == {"person/carol"}


@pytest.mark.parametrize("node", NODES)
def test_ros2_run_each_node(node, ros_domain):
    result = _ros2("run", "nmrm_ros", node, "--help")
    assert result.returncode == 0 and "parameters (ros__parameters):" in result.stdout, result.stderr


def test_ros2_run_refuses_a_wrong_typed_parameter(ros_domain):
    result = _ros2("run", "nmrm_ros", "env_sim", "--ros-args", "-p", "episodes:=abc")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1] == \
        "[env_sim] error: parameter 'episodes' must be an integer, got a string 'abc'"


# -- the typing rules: nmrm launch's parameter_value against launch_ros itself ---------------------
CASES = [True, 5, 1.0, "true", "1.0", "abc", "['/a']", ["a", "b"], [1, 2], [1.5, 2.5],
         "$(var x)", "$(var x)/policy", ["$(var x)", "$(var x)"]]
VARIABLES = ["5", "1.0", "true", "abc", "", "['/a', '/b']", "[1, 2]"]


def _launch_ros_value(raw, x: str):
    """What launch_ros gives a node for `{name: p, value: raw}` in a YAML launch file."""
    from launch import LaunchContext
    from launch.frontend.parse_substitution import parse_if_substitutions
    from launch_ros.descriptions import ParameterValue

    context = LaunchContext()
    context.launch_configurations["x"] = x
    value = ParameterValue(parse_if_substitutions(raw), value_type=None).evaluate(context)
    return list(value) if isinstance(value, (list, tuple)) else value


@pytest.mark.parametrize("raw", CASES, ids=str)
def test_nmrm_launch_types_parameters_like_launch_ros(raw):
    from nmrm_ros.launcher import LaunchError, parameter_value

    for x in VARIABLES:
        try:
            expected = _launch_ros_value(raw, x)
        except Exception as exc:  # noqa: BLE001 - launch_ros refuses: so must we
            with pytest.raises(LaunchError):
                parameter_value(raw, {"x": x}, "p")
            continue
        got = parameter_value(raw, {"x": x}, "p")
        assert (got, type(got)) == (expected, type(expected)), (raw, x)
