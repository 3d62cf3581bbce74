"""A robot in standard messages: field paths, the robot spec, and the two bridges as real node
processes over real topics (Odometry and LaserScan in, EnvObservation out; AgentAction in, Twist
out, with the safe stop)."""

from __future__ import annotations

import math
import signal
import time

import numpy as np
import pytest

from nmrm_ros.ros.field_paths import compile_fields, sectors, yaw
from nmrm_ros.ros.robot_spec import parse_robot_spec

SPEC = """
observation:
  rate: 20.0
  stale_after: 0.3
  inputs:
    - {topic: /odom, type: nav_msgs/msg/Odometry, qos: sensor_data, fields: [pose.pose.position.x, pose.pose.position.y]}
episode:
  max_steps: 10
  box: {dims: [0], low: [-1.0], high: [1.0]}
action:
  topic: /cmd_vel
  rate: 20.0
  timeout: 0.3
  discrete:
    0: {linear.x: 0.2}
    1: {angular.z: 1.0}
"""


# -- core (no ROS graph) -------------------------------------------------------------------------
def test_field_paths_read_the_standard_messages():
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState, LaserScan
    from std_msgs.msg import Float32MultiArray

    odom = Odometry()
    odom.pose.pose.position.x, odom.pose.pose.position.y = 1.5, -2.0
    odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(0.3), math.cos(0.3)  # yaw 0.6
    read = compile_fields("nav_msgs/msg/Odometry", ["pose.pose.position.x", "pose.pose.position.y",
                                                    "yaw(pose.pose.orientation)"])
    assert read(odom) == pytest.approx([1.5, -2.0, 0.6])
    pose = PoseStamped()
    pose.pose.orientation.w = 1.0
    assert compile_fields("geometry_msgs/PoseStamped", ["yaw(pose.orientation)"])(pose) == [0.0]
    joints = JointState(name=["left", "right"], position=[0.1, 0.2], velocity=[3.0, 4.0])
    assert compile_fields("sensor_msgs/msg/JointState", ["position[right]", "velocity[0]"])(joints) == [0.2, 3.0]
    scan = LaserScan(ranges=[1.0, float("inf"), 3.0, 0.5, float("nan"), 2.0, 4.0, 4.0], range_max=10.0)
    assert compile_fields("sensor_msgs/msg/LaserScan", ["ranges"], downsample=4)(scan) == [1.0, 0.5, 2.0, 4.0]
    arr = Float32MultiArray(data=[7.0, 8.0])
    assert compile_fields("std_msgs/msg/Float32MultiArray", ["data[1]", "data"])(arr) == [8.0, 7.0, 8.0]


def test_field_path_mistakes_are_one_line_errors():
    from sensor_msgs.msg import JointState

    with pytest.raises(ValueError, match="has no field 'positio'"):
        compile_fields("nav_msgs/msg/Odometry", ["pose.pose.positio.x"])
    with pytest.raises(ValueError, match="unknown message type"):
        compile_fields("nav_msgs/msg/Odometri", ["x"])
    with pytest.raises(ValueError, match="cannot read field path"):
        compile_fields("nav_msgs/msg/Odometry", ["pose..x["])
    read = compile_fields("sensor_msgs/msg/JointState", ["position[elbow]"])
    with pytest.raises(ValueError, match="no joint 'elbow'"):
        read(JointState(name=["left"], position=[0.0]))
    read = compile_fields("sensor_msgs/msg/JointState", ["position[0]"])
    with pytest.raises(ValueError, match="not finite"):
        read(JointState(name=["left"], position=[float("nan")]))
    with pytest.raises(ValueError, match="cannot make 4 sectors"):
        sectors([1.0, 2.0], 4, 10.0)
    assert yaw(type("Q", (), {"x": 0.0, "y": 0.0, "z": 1.0, "w": 0.0})()) == pytest.approx(math.pi)


@pytest.mark.parametrize("text,message", [
    ("observation: {inputs: []}", "observation.inputs must be a non-empty list"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry}]}", r"observation.inputs\[0\].fields is missing"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [x.y]}]}", "has no field 'x'"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [pose.pose.position.x], qos: best}]}",
     "qos must be one of"),
    ("observation: {rate: 0, inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [pose.pose.position.x]}]}",
     "observation.rate must be > 0"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [pose.pose.position.x]}]}\n"
     "action: {discrete: {0: {linear.w: 1}}}", "are not twist fields"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [pose.pose.position.x]}]}\n"
     "action: {continuous: {fields: [linear.x], low: [1], high: [0]}}", "every low must be <= its high"),
    ("observation: {inputs: [{topic: /o, type: nav_msgs/msg/Odometry, fields: [pose.pose.position.x]}]}\n"
     "episode: {max_steps: -1}", "episode.max_steps must be a whole number"),
    ("robot: 1", "unknown section"),
    ("[1, 2", "is not YAML"),
])
def test_robot_spec_mistakes_name_the_key(text, message):
    with pytest.raises(ValueError, match=message):
        parse_robot_spec(text)


def test_both_bridges_refuse_a_missing_or_wrong_spec_file_in_one_line(tmp_path):
    from nmrm_ros.ros.node_main import NodeError, require_robot_spec

    (tmp_path / "list.yaml").write_text("[1, 2]")
    for path, message in [("", "spec is required"), (str(tmp_path / "none.yaml"), "no robot spec file"),
                          (str(tmp_path), "no robot spec file"), (str(tmp_path / "list.yaml"), "must be a mapping")]:
        with pytest.raises(NodeError, match=message) as err:
            require_robot_spec(path)
        assert "\n" not in str(err.value)


def test_the_action_table_and_the_limits():
    spec = parse_robot_spec(SPEC)
    assert spec.twist([1.0]) == {"angular.z": 1.0}
    with pytest.raises(ValueError, match="not one of"):
        spec.twist([2.0])
    cont = parse_robot_spec(SPEC.split("action:")[0] + "action: {continuous: {fields: [linear.x, angular.z], "
                                                       "low: [-0.2, -1.0], high: [0.2, 1.0]}}")
    assert cont.twist([5.0, -0.5]) == {"linear.x": 0.2, "angular.z": -0.5}
    assert spec.left_box([1.5, 0.0]) and not spec.left_box([0.5, 9.0])


# -- the bridges as processes --------------------------------------------------------------------
def _odometry(x: float, y: float):
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    return msg


def test_observation_bridge_makes_episodes_from_odometry(ros_domain, tmp_path):
    """Odometry at 50 Hz -> observations at 20 Hz: episodes of 10 steps (truncated) then one that
    leaves the box (terminated); with the odometry gone, nothing is published and the stale ticks
    are counted; ~/end_episode ends an episode by service."""
    from rclpy.qos import qos_profile_sensor_data
    from std_srvs.srv import Trigger

    from nmrm_ros.testing.graph import Capture, finish, start
    from nav_msgs.msg import Odometry

    (tmp_path / "robot.yaml").write_text(SPEC)
    capture = Capture()
    # wait_for_subscribers=1: the bridge's own publisher must have matched the capture before episode 0
    # starts. Seeing the bridge's publisher from the capture's side (count_publishers) is not enough:
    # the writer may not yet have matched the reader, and a volatile writer drops what it sends before
    # (CI lost steps 0-5 of episode 0 that way, twice)
    bridge = start("observation_bridge", spec=tmp_path / "robot.yaml", task="key", episodes=3,
                   wait_for_subscribers=1)
    try:
        odom = capture.node.create_publisher(Odometry, "/odom", qos_profile_sensor_data)
        assert capture.spin_until(lambda: odom.get_subscription_count() >= 1, 30)
        capture.wait_for_publishers({"observation": 1}, timeout=30)
        x = 0.0
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(m.terminated for m in capture.msgs["observation"]):
            eps = {m.episode for m in capture.msgs["observation"]}
            if len([e for e in eps if any(m.truncated and m.episode == e for m in capture.msgs["observation"])]) >= 2:
                x = 1.05  # after two truncated episodes, out of the box at once (a ramp lost the
                # race against the third episode's 10 steps on a loaded machine)
            odom.publish(_odometry(x, 0.5))
            capture.spin_for(0.02)
        assert capture.spin_until(lambda: bridge.poll() is not None, 30)
        code, out = finish(bridge)
    finally:
        if bridge.poll() is None:
            bridge.send_signal(signal.SIGINT)
        capture.close()
    obs = capture.msgs["observation"]
    by_episode = {}
    for m in obs:
        by_episode.setdefault(m.episode, []).append(m)
    assert sorted(by_episode) == [0, 1, 2], out
    for e in (0, 1):
        steps = [m.step for m in by_episode[e]]
        assert steps == list(range(11)) and by_episode[e][-1].truncated and not by_episode[e][-1].terminated
        assert all(m.task == "key" and list(m.state) == pytest.approx([0.0, 0.5]) for m in by_episode[e])
    assert by_episode[2][-1].terminated and by_episode[2][-1].state[0] >= 1.0  # float32 of just over 1
    assert code == 0 and "3 episode(s)" in out, out

    # stale input and episodes by service
    capture = Capture()
    bridge = start("observation_bridge", spec=tmp_path / "robot.yaml", task="key", auto_start=False)
    try:
        odom = capture.node.create_publisher(Odometry, "/odom", qos_profile_sensor_data)
        client = capture.node.create_client(Trigger, "/observation_bridge/start_episode")
        ender = capture.node.create_client(Trigger, "/observation_bridge/end_episode")
        assert capture.spin_until(lambda: client.service_is_ready() and ender.service_is_ready(), 30)
        capture.spin_for(0.5)
        assert capture.msgs["observation"] == []  # no episode started

        def call(c):
            future = c.call_async(Trigger.Request())
            assert capture.spin_until(future.done, 10)
            return future.result()

        assert call(client).success
        capture.spin_for(0.5)
        assert capture.msgs["observation"] == []  # started, but the odometry was never seen: stale
        for _ in range(5):
            odom.publish(_odometry(0.1, 0.2))
            capture.spin_for(0.05)
        assert capture.spin_until(lambda: len(capture.msgs["observation"]) >= 2, 10)
        odom.publish(_odometry(0.1, 0.2))
        capture.spin_for(0.02)
        answer = call(ender)
        assert answer.success, answer.message
        assert capture.spin_until(lambda: capture.msgs["observation"][-1].truncated, 5)
        assert not call(ender).success  # nothing running any more
        bridge.send_signal(signal.SIGINT)
        code, out = finish(bridge)
    finally:
        capture.close()
    final = capture.msgs["observation"][-1]
    assert final.episode == 0 and final.step == len(capture.msgs["observation"]) - 1
    assert "/odom is stale (never received)" in out and code == 0, out


def test_action_bridge_sends_twists_and_stops_safely(ros_domain, tmp_path):
    """Action 1 -> angular.z 1.0 at the spec's rate; no action for 0.3 s -> zero twists; a final
    observation -> a zero twist at once; an unknown index is dropped with a warning."""
    from geometry_msgs.msg import Twist

    from nmrm_ros.testing.graph import Capture, finish, start
    from nmrm_msgs.msg import AgentAction, EnvObservation
    from nmrm_ros.ros.topics import ACTION, OBSERVATION

    (tmp_path / "robot.yaml").write_text(SPEC)
    capture = Capture()
    twists: list = []
    capture.node.create_subscription(Twist, "/cmd_vel", lambda m: twists.append((time.monotonic(), m)), 10)
    bridge = start("action_bridge", spec=tmp_path / "robot.yaml")
    try:
        act = capture.publisher(AgentAction, ACTION)
        obs = capture.publisher(EnvObservation, OBSERVATION)
        assert capture.spin_until(lambda: act.get_subscription_count() >= 1 and obs.get_subscription_count() >= 1
                                  and len(twists) > 0, 30)
        sent = time.monotonic()
        act.publish(AgentAction(episode=0, step=0, action=[1.0]))
        assert capture.spin_until(lambda: any(m.angular.z == 1.0 for t, m in twists if t > sent), 5)
        capture.spin_for(0.8)  # no more actions: the safe stop after 0.3 s
        late = [m for t, m in twists if t > sent + 0.6]
        assert late and all(m.angular.z == 0.0 and m.linear.x == 0.0 for m in late)
        act.publish(AgentAction(episode=1, step=0, action=[0.0]))
        assert capture.spin_until(lambda: twists[-1][1].linear.x == pytest.approx(0.2), 5)
        ended = time.monotonic()
        obs.publish(EnvObservation(task="key", episode=1, step=5, state=[0.0, 0.0], truncated=True))
        assert capture.spin_until(lambda: any(t > ended and m.linear.x == 0.0 for t, m in twists), 2)
        first_zero = min(t for t, m in twists if t > ended and m.linear.x == 0.0)
        assert first_zero - ended < 0.3  # at once, not only at the timeout
        act.publish(AgentAction(episode=2, step=0, action=[7.0]))
        capture.spin_for(0.3)
        bridge.send_signal(signal.SIGINT)
        code, out = finish(bridge)
    finally:
        capture.close()
    assert code == 0 and "action of episode 2 step 0 dropped (1 so far): action [7.0] is not one of [0, 1]" in out, out


def test_the_fake_robot_end_to_end_through_the_bridges(ros_domain, tmp_path):
    """robot_bridge.launch.yaml with the fake unicycle (a faster spec: 40 Hz, 20 steps) and the
    Foxglove server: 10 episodes recorded from Odometry, each labelled by the delivery oracle, the
    agent's actions reaching the robot as twists; the graph ends by itself; a model trains on the bag."""
    import subprocess

    from nmrm_ros.testing.graph import executable
    from nmrm_ros.bags.episodes import load_bag_dataset

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    spec = (root / "config" / "robots" / "fake_delivery.yaml").read_text()
    spec = spec.replace("rate: 10.0", "rate: 40.0").replace("max_steps: 200", "max_steps: 20")
    (tmp_path / "fast.yaml").write_text(spec)
    res = subprocess.run([executable("nmrm"), "launch", str(root / "launch_scripts" / "robot_bridge.launch.yaml"),
                          f"spec:={tmp_path / 'fast.yaml'}", "episodes:=10", f"out:={tmp_path / 'bag'}",
                          "task:=nmrm_ros.robots.delivery:DeliveryEnv,max_steps=20,xy=0/1",
                          "foxglove:=true", "foxglove_port:=0"],
                         capture_output=True, text=True, timeout=240)
    assert res.returncode == 0 and "all 9 node(s) exited cleanly" in res.stdout, res.stdout[-3000:] + res.stderr
    assert "serving /nmrm/viz/arena" in res.stdout  # the Foxglove server came and went with the graph
    ds, report = load_bag_dataset([tmp_path / "bag"])
    assert report.episodes_used == 10 and ds.state_size == 3 and set(ds.lengths) == {20}, str(report)
    assert "episode end stop(s), 0 action(s) dropped" in res.stdout, res.stdout[-2000:]
    moved = np.abs(np.diff(ds.states[:, :, :2], axis=1)).sum()
    assert moved > 0.1  # the random agent's twists moved the robot
    train = subprocess.run([executable("nmrm"), "train", "--bag", str(tmp_path / "bag"), "--epochs", "2",
                            "--out", str(tmp_path / "m")], capture_output=True, text=True, timeout=240)
    assert train.returncode == 0 and "checkpoint:" in train.stdout, train.stdout + train.stderr


def test_the_visualizer_publishes_standard_topics(ros_domain):
    """A real visualizer (task key): the arena as a latched MarkerArray (a late subscriber gets
    it), the agent's PoseStamped and Path in the fixed frame, the served reward and hidden state
    as plottable std_msgs, and /diagnostics with the steps and the model served."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import Float32, Float32MultiArray
    from visualization_msgs.msg import MarkerArray

    from nmrm_ros.testing.graph import Capture, finish, start
    from nmrm_msgs.msg import EnvObservation, RewardStep
    from nmrm_ros.ros.topics import OBSERVATION, REWARD_STEP

    capture = Capture()
    viz = start("visualizer", task="key")
    got: dict = {k: [] for k in ("arena", "pose", "path", "reward", "hidden", "diag")}
    try:
        obs = capture.publisher(EnvObservation, OBSERVATION)
        rew = capture.publisher(RewardStep, REWARD_STEP)
        assert capture.spin_until(lambda: obs.get_subscription_count() >= 1 and rew.get_subscription_count() >= 1, 30)
        capture.spin_for(0.5)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node = capture.node
        node.create_subscription(MarkerArray, "/nmrm/viz/arena", got["arena"].append, latched)  # after it was sent
        node.create_subscription(PoseStamped, "/nmrm/viz/pose", got["pose"].append, 10)
        node.create_subscription(Path, "/nmrm/viz/path", got["path"].append, 10)
        node.create_subscription(Float32, "/nmrm/viz/reward", got["reward"].append, 10)
        node.create_subscription(Float32MultiArray, "/nmrm/viz/hidden", got["hidden"].append, 10)
        node.create_subscription(DiagnosticArray, "/diagnostics", got["diag"].append, 10)
        assert capture.spin_until(lambda: got["arena"], 10)
        capture.spin_for(1.0)
        for t in range(5):
            obs.publish(EnvObservation(task="key", episode=0, step=t, state=[0.1 * t, 0.5]))
            rew.publish(RewardStep(episode=0, step=t, reward=0.25 * t, hidden=[0.5, -0.5], source="key_v001"))
            capture.spin_for(0.05)
        assert capture.spin_until(lambda: len(got["path"]) >= 5 and len(got["hidden"]) >= 5, 10)
        assert capture.spin_until(lambda: any({kv.key: kv.value for kv in s.values}.get("model") == "key_v001"
                                              for d in got["diag"] for s in d.status), 5)
        viz.send_signal(signal.SIGINT)
        code, out = finish(viz)
    finally:
        capture.close()
    kinds = [m.ns for m in got["arena"][0].markers]
    assert {"spawn", "treasure", "key", "bounds"} <= set(kinds) and all(m.header.frame_id == "map"
                                                                          for m in got["arena"][0].markers)
    assert got["pose"][-1].header.frame_id == "map" and got["pose"][-1].pose.position.x == pytest.approx(0.4)
    assert len(got["path"][-1].poses) == 5
    assert [r.data for r in got["reward"]][-1] == pytest.approx(1.0)
    assert list(got["hidden"][-1].data) == [0.5, -0.5]
    assert code == 0, out


def test_nmrm_launch_honours_node_conditions(tmp_path):
    """`if:` / `unless:` on a node, as launch evaluates them: fake_robot:=false leaves the fake
    robot out; a value that is not true/false/1/0 is a one-line LaunchError."""
    from pathlib import Path

    from nmrm_ros.launcher import LaunchError, parse_launch_file

    path = Path(__file__).resolve().parents[1] / "launch_scripts" / "robot_bridge.launch.yaml"
    names = lambda args: [n.name for n in parse_launch_file(path, args, params_dir=tmp_path)]  # noqa: E731
    assert "fake_robot" in names({}) and "fake_robot" in names({"fake_robot": "True"})
    assert "fake_robot" not in names({"fake_robot": "false"}) and "observation_bridge" in names({"fake_robot": "0"})
    with pytest.raises(LaunchError, match="is not true, false, 1 or 0"):
        names({"fake_robot": "maybe"})


def test_every_node_reports_on_diagnostics(ros_domain, tmp_path):
    """Each node, started on its own, publishes its status on /diagnostics once a second: named
    `nmrm: /<node>`, with its counters as key/values (and a rate for the one it counts)."""
    from diagnostic_msgs.msg import DiagnosticArray

    from nmrm_ros.testing.graph import Capture, finish, start

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    spec = str(root / "config" / "robots" / "fake_delivery.yaml")
    delivery = "nmrm_ros.robots.delivery:DeliveryEnv,max_steps=200,xy=0/1"
    nodes = {
        "env_sim": dict(task="key", wait_for_subscribers=9, startup_timeout=60.0),
        "reward_model": dict(task="key", mode="oracle"),
        "labeller_oracle": dict(task="key"),
        "agent": dict(task="key"),
        "recorder": dict(output=str(tmp_path / "bag")),
        "visualizer": dict(task="key"),
        "trainer": dict(task="key", out_dir=str(tmp_path / "trainer")),
        "labeller_web": dict(task="key", port=0, labels_dir=str(tmp_path / "labels")),
        "observation_bridge": dict(spec=spec, task=delivery, auto_start=False),
        "action_bridge": dict(spec=spec),
        "fake_robot": dict(),
    }
    capture = Capture()
    seen: dict = {}
    capture.node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: seen.update({s.name: {kv.key: kv.value for kv in s.values} for s in m.status}), 50)
    procs = {name: start(name, **params) for name, params in nodes.items()}
    try:
        names = {f"nmrm: /{name}" for name in nodes}
        assert capture.spin_until(lambda: names <= set(seen), 60), sorted(set(seen))
    finally:
        for p in procs.values():
            p.send_signal(signal.SIGINT)
        outs = {name: finish(p) for name, p in procs.items()}
        capture.close()
    assert all(code == 0 for code, _ in outs.values()), {n: o[-1500:] for n, (c, o) in outs.items() if c}
    assert seen["nmrm: /env_sim"]["steps_per_second"] == "0.00" and seen["nmrm: /reward_model"]["mode"] == "oracle"
    assert seen["nmrm: /trainer"]["model_version"] == "0" and "dropped /odom" in seen["nmrm: /observation_bridge"]


def test_a_person_labels_the_robots_episodes(ros_domain, tmp_path):
    """robot_bridge.launch.yaml label:=true: the fake robot's episodes wait on the labelling page
    (all three, the first included: subscribers:=6); a label posted to the page's API is in the
    person's labels bag beside the oracle's; the page keeps the graph up until Ctrl-C."""
    import os
    import subprocess

    from nmrm_ros.testing.graph import OutputLines, executable
    from nmrm_ros.bags import iter_decoded
    from nmrm_ros.labelling.client import PageClient

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    spec = (root / "config" / "robots" / "fake_delivery.yaml").read_text()
    (tmp_path / "fast.yaml").write_text(spec.replace("rate: 10.0", "rate: 40.0").replace("max_steps: 200", "max_steps: 20"))
    out = tmp_path / "robot"
    proc = subprocess.Popen([executable("nmrm"), "launch", str(root / "launch_scripts" / "robot_bridge.launch.yaml"),
                             f"spec:={tmp_path / 'fast.yaml'}", "episodes:=3", f"out:={out}", "label:=true",
                             "subscribers:=6", "port:=0", "person:=dana",
                             "task:=nmrm_ros.robots.delivery:DeliveryEnv,max_steps=20,xy=0/1"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    output = OutputLines(proc)
    wait_for = output.wait_for

    try:
        url = wait_for("labelling page: ").split("labelling page: ")[1].split()[0]
        wait_for("waits for a label", count=3)
        page = PageClient(url)
        queue = page.get("/api/queue")["episodes"]
        assert sorted(e["episode"] for e in queue) == [0, 1, 2], queue
        page.post("/api/label", {"episode": 1, "return": 3.5})
        wait_for("labelled 3 episode(s)")  # the oracle labeller too, then it leaves with the robot
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(60)
        output.reader.join(10)
    text = output.text()
    assert code == 130 and "interrupted by SIGINT" in text, text[-3000:]
    labels = [m for bag in out.parent.glob("robot_labels/person_*") for _, _, _, m in iter_decoded(bag)]
    assert [(m.episode, m.return_value, m.labeller) for m in labels] == [(1, 3.5, "person/dana")]


def test_an_agent_learns_through_the_robot_bridges(ros_domain, tmp_path):
    """robot_bridge.launch.yaml policy:=learn: the double-DQN agent learns from the reward steps of
    the fake robot's episodes (the oracle's reward here; mode:=model serves a checkpoint's), its
    actions reach the robot as twists, and it saves its policy and curve when the bridge is done."""
    import subprocess

    from nmrm_ros.testing.graph import executable

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    spec = (root / "config" / "robots" / "fake_delivery.yaml").read_text()
    (tmp_path / "fast.yaml").write_text(spec.replace("rate: 10.0", "rate: 40.0").replace("max_steps: 200", "max_steps: 20"))
    res = subprocess.run([executable("nmrm"), "launch", str(root / "launch_scripts" / "robot_bridge.launch.yaml"),
                          f"spec:={tmp_path / 'fast.yaml'}", "episodes:=4", f"out:={tmp_path / 'bag'}", "policy:=learn",
                          "task:=nmrm_ros.robots.delivery:DeliveryEnv,max_steps=20,xy=0/1"],
                         capture_output=True, text=True, timeout=240)
    assert res.returncode == 0 and "all 8 node(s) exited cleanly" in res.stdout, res.stdout[-3000:] + res.stderr
    assert "learner finished 4 episodes" in res.stdout, res.stdout[-3000:]
    agent = tmp_path / "bag_agent"
    assert (agent / "policy.zip").is_file() and len((agent / "curve.csv").read_text().splitlines()) == 5
