"""MCAP bags: recording the live graph, clean and hard stops, repair, replay, training from bags."""

import signal
import time

import numpy as np
import pytest
import torch
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from nmrm_ros.testing.graph import Capture, executable, finish, start
from nmrm_msgs.msg import EnvObservation, TrajectoryReturn
from nmrm_ros.bags import (BagError, BagWriter, bag_summary, iter_decoded, load_bag_dataset, repair_bag,
                           write_dataset_bag)
from nmrm_ros.datasets import generate_screened
from nmrm_ros.mil import build_model, load_train_config, model_config, train_model
from nmrm_ros.mil.data import split_indices
from nmrm_ros.ros.topics import OBSERVATION, TRAJECTORY_RETURN

import subprocess
from pathlib import Path

LAUNCH = Path(__file__).resolve().parents[1] / "launch_scripts" / "collect.launch.yaml"


@pytest.fixture
def capture(ros_domain):
    cap = Capture()
    yield cap
    cap.close()


def _rosbags_messages(path):
    out = []
    with AnyReader([Path(path)]) as reader:
        for conn, _, raw in reader.messages():
            out.append((conn.topic, reader.deserialize(raw, conn.msgtype)))
    return out


def test_live_graph_recorded_exactly(capture, tmp_path):
    """The collect graph's recording holds exactly what was published, for rosbags and mcap."""
    out = tmp_path / "live"
    _record_live(capture, out)
    _check_live_recording(capture, out)


def _record_live(capture, out):
    # env_sim waits for labeller, agent, recorder and this capture (4 observation subscribers);
    # the capture only checks observations, so it needs no other publisher matched
    proc = subprocess.Popen([executable("nmrm"), "launch", str(LAUNCH), "episodes:=3", f"out:={out}",
                             "wait_for_subscribers:=4", "start_delay:=1.0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    capture.spin_until(lambda: proc.poll() is not None, 90)
    code, log = finish(proc)
    capture.spin_for(0.3)
    assert code == 0, log
    return log


def _check_live_recording(capture, out):
    assert (out / "metadata.yaml").is_file()
    recorded = _rosbags_messages(out)
    obs = [m for t, m in recorded if t == "/nmrm/observation"]
    assert [(m.episode, m.step) for m in obs] == [(e, t) for e in range(3) for t in range(101)]
    labels = [m for t, m in recorded if t == "/nmrm/trajectory_return"]
    assert [(m.episode, m.length, m.labeller) for m in labels] == [(e, 100, "oracle/key") for e in range(3)]
    # the same through the mcap library, and equal to what a live subscriber received
    with open(next(out.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary.statistics.message_count == len(recorded)
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    live = [(m.episode, m.step, list(m.state)) for m in capture.msgs["observation"]]
    assert live == [(m.episode, m.step, list(map(float, m.state))) for m in obs]
    decoded = [m for t, _, _, m in iter_decoded(out) if t == "/nmrm/trajectory_return"]
    assert [m.return_value for m in decoded] == [m.return_value for m in labels]


def _publish_episodes(capture, n_episodes, length=100, task="key"):
    pub = capture.publisher(EnvObservation, OBSERVATION)
    lab = capture.publisher(TrajectoryReturn, TRAJECTORY_RETURN)
    assert capture.spin_until(lambda: pub.get_subscription_count() >= 2 and lab.get_subscription_count() >= 2, 30)
    rng = np.random.default_rng(0)
    for e in range(n_episodes):
        for t in range(length + 1):
            pub.publish(EnvObservation(task=task, episode=e, step=t, state=rng.uniform(0, 1, 2).tolist(),
                                       truncated=t == length))
        lab.publish(TrajectoryReturn(task=task, episode=e, length=length, return_value=float(e),
                                     labeller="oracle/key"))
        capture.spin_for(0.01)
    # the recorder has them once it acknowledged them: our side matching it (the subscription
    # count above) does not mean it matched us yet, and the reliable resend can take a heartbeat
    from rclpy.duration import Duration

    for p in (pub, lab):
        assert p.wait_for_all_acked(Duration(seconds=30))
    capture.spin_for(0.5)


def test_sigint_leaves_a_readable_bag(capture, tmp_path):
    out = tmp_path / "rec"
    rec = start("recorder", output=str(out))
    _publish_episodes(capture, 5)
    assert len(capture.msgs["observation"]) == 505
    rec.send_signal(signal.SIGINT)
    code, log = finish(rec)
    assert code == 0, log
    summary = bag_summary(out)
    assert summary["/nmrm/observation"] == ("nmrm_msgs/msg/EnvObservation", 505)
    ds, report = load_bag_dataset([out])
    assert report.episodes_used == 5 and ds.returns.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_the_recorder_subscribes_to_observations_once_it_knows_their_publisher(capture, tmp_path):
    """A producer starts when it sees the recorder's observation subscription, and cannot see
    whether the recorder's side has matched it yet: so that subscription is made only once the
    recorder knows the publisher (it then matches at once), or after observation_wait s. Steps
    published the moment the subscription appears are all recorded."""
    from rclpy.duration import Duration

    out = tmp_path / "rec"
    rec = start("recorder", output=str(out), observation_wait=60.0)
    node = capture.node

    def recorder_on(topic):
        return any(i.node_name == "recorder" for i in node.get_subscriptions_info_by_topic("/" + topic))

    assert capture.spin_until(lambda: recorder_on(TRAJECTORY_RETURN), 30)
    capture.spin_for(1.0)
    assert not recorder_on(OBSERVATION)  # no observation publisher yet: not subscribed
    pub = capture.publisher(EnvObservation, OBSERVATION)
    assert capture.spin_until(lambda: pub.get_subscription_count() >= 2, 30)  # the recorder, the capture
    for t in range(501):  # many, SIGINT right after they are acknowledged: none lost (drain_on_stop)
        pub.publish(EnvObservation(task="key", episode=0, step=t, state=[0.0, 1.0], truncated=t == 500))
    assert pub.wait_for_all_acked(Duration(seconds=30))
    rec.send_signal(signal.SIGINT)
    code, log = finish(rec)
    assert code == 0, log
    steps = [m.step for t, _, _, m in iter_decoded(out) if t == "/" + OBSERVATION]
    assert steps == list(range(501)), log
    # with nobody publishing, it subscribes after observation_wait all the same
    rec = start("recorder", output=str(tmp_path / "alone"), observation_wait=0.5)
    try:
        assert capture.spin_until(lambda: recorder_on(OBSERVATION), 30)
    finally:
        rec.send_signal(signal.SIGINT)
        finish(rec)


def test_hard_kill_then_repair_recovers_complete_episodes(capture, tmp_path):
    out = tmp_path / "killed"
    rec = start("recorder", output=str(out), chunk_size=16384, flush_period=0.2)
    _publish_episodes(capture, 30)
    time.sleep(1.0)  # idle for 5 flush periods: the chunk in progress was ended and flushed
    rec.send_signal(signal.SIGKILL)
    finish(rec)
    assert not (out / "metadata.yaml").exists()
    with pytest.raises(BagError, match="nmrm bag repair"):
        bag_summary(out)
    report = repair_bag(out)
    assert report.messages > 0 and report.backup.exists()
    ds, episodes = load_bag_dataset([out])
    # everything received before the idle second is back (finding 4 of issue 10: the recorder
    # never flushed its last partial chunk while idle and lost 5.2%), each episode correct
    assert episodes.episodes_used == 30
    assert ds.returns.tolist() == [float(e) for e in ds.meta["episodes"]]
    assert np.all(ds.lengths == 100)
    assert _rosbags_messages(out)  # readable by rosbags too


def test_truncated_bag_gives_clear_error_and_repair(tmp_path):
    ds = generate_screened("key", 40, seed=0)
    path = write_dataset_bag(ds, tmp_path / "bag")
    file = next(path.glob("*.mcap"))
    data = file.read_bytes()
    file.write_bytes(data[: int(len(data) * 0.6)])
    (path / "metadata.yaml").unlink()
    with pytest.raises(BagError, match="did not close"):
        load_bag_dataset([path])
    report = repair_bag(path)
    back, rep = load_bag_dataset([path])
    assert 0 < rep.episodes_used < 40
    for i, e in enumerate(back.meta["episodes"]):  # recovered episodes are the originals
        np.testing.assert_array_equal(back.states[i], ds.states[e])
        assert back.returns[i] == ds.returns[e]
    assert report.damaged


def test_malformed_bags(tmp_path):
    with pytest.raises(BagError, match="no bag"):
        bag_summary(tmp_path / "nothing")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    with pytest.raises(BagError, match="malformed"):
        bag_summary(tmp_path / "bad")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "junk_0.mcap").write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(BagError):
        repair_bag(tmp_path / "junk")


def test_replay_reproduces_messages(capture, tmp_path):
    ds = generate_screened("charger", 5, seed=1)
    path = write_dataset_bag(ds, tmp_path / "bag")
    rp = start("replay", bag=str(path), wait_for_subscribers=1)
    capture.spin_until(lambda: rp.poll() is not None, 60)
    code, log = finish(rp, 60)
    capture.spin_for(0.5)
    assert code == 0, log
    sent = [(t, m) for t, _, _, m in iter_decoded(path)]
    got_obs = [(m.episode, m.step, list(m.state)) for m in capture.msgs["observation"]]
    assert got_obs == [(m.episode, m.step, list(m.state)) for t, m in sent if t == "/nmrm/observation"]
    assert [(m.episode, m.return_value) for m in capture.msgs["label"]] == \
        [(m.episode, m.return_value) for t, m in sent if t == "/nmrm/trajectory_return"]
    assert len(capture.msgs["oracle_step"]) == 500 and len(capture.msgs["action"]) == 500


def test_a_bag_of_an_older_observation_definition_replays(capture):
    """bags/key_screened was recorded before EnvObservation gained `privileged`: replay re-encodes
    its observations with today's definition (privileged empty), so today's subscribers read them."""
    bag = Path(__file__).resolve().parents[1] / "bags" / "key_screened"
    rp = start("replay", bag=str(bag), topics=["/nmrm/observation"], wait_for_subscribers=1, rate=0.0)
    capture.spin_until(lambda: rp.poll() is not None, 90)
    code, log = finish(rp, 60)
    capture.spin_for(0.5)
    assert code == 0, log
    sent = [m for t, _, _, m in iter_decoded(bag, ["/nmrm/observation"])]
    got = capture.msgs["observation"]
    assert len(got) == len(sent) > 0
    assert [(m.episode, m.step, list(m.state)) for m in got] == [(m.episode, m.step, list(m.state)) for m in sent]
    assert all(len(m.privileged) == 0 for m in got)


def test_replay_as_fast_as_possible_waits_for_a_slow_subscriber(capture, tmp_path):
    """rate 0 with 120 episodes (12,120 observations) to a subscriber that takes nothing for 3 s:
    the writer's keep-all history fills (the DDS resource limits) and replay waits for the
    subscriber instead of dying; every observation arrives, in order."""
    ds = generate_screened("key", 120, seed=2)
    path = write_dataset_bag(ds, tmp_path / "bag", include_oracle=False)
    rp = start("replay", bag=str(path), wait_for_subscribers=1, topics="[/nmrm/observation]")
    capture.wait_for_publishers({"observation": 1})
    time.sleep(3.0)  # not spinning: the subscriber takes nothing
    assert capture.spin_until(lambda: rp.poll() is not None, 120)
    code, log = finish(rp, 60)
    capture.spin_for(0.5)
    assert code == 0, log
    got = [(m.episode, m.step) for m in capture.msgs["observation"]]
    assert got == [(e, t) for e in range(120) for t in range(int(ds.lengths[e]) + 1)], log


def test_replay_stops_at_once_on_sigint(capture, tmp_path):
    """Observations 10 ms apart played at rate 0.001 (one every 10 s): SIGINT after the first ends
    the replay at once, exit 0, saying how far it got (it publishes in short slices, between which
    the node handles signals; before, the whole bag was published inside one timer callback)."""
    ds = generate_screened("key", 10, seed=4)
    path = write_dataset_bag(ds, tmp_path / "bag", include_oracle=False)
    rp = start("replay", bag=str(path), rate=0.001, topics="[/nmrm/observation]")
    assert capture.spin_until(lambda: len(capture.msgs["observation"]) >= 1, 30)
    t0 = time.monotonic()
    rp.send_signal(signal.SIGINT)
    code, log = finish(rp, 30)
    assert code == 0 and time.monotonic() - t0 < 5.0, log
    assert "stopped after 1 messages" in log, log


def test_training_from_bag_equals_training_in_memory(tmp_path):
    ds = generate_screened("key", 200, seed=3)
    path = write_dataset_bag(ds, tmp_path / "bag")
    from_bag, report = load_bag_dataset([path])
    assert report.episodes_used == 200 and report.with_oracle == 200
    for k in ("states", "lengths", "returns", "final_states"):
        np.testing.assert_array_equal(getattr(from_bag, k), getattr(ds, k))
    np.testing.assert_allclose(from_bag.rewards, ds.rewards, atol=1e-6)
    weights = []
    for data in (ds, from_bag):
        tr, va, _ = split_indices(len(data), 0)
        cfg = load_train_config("key", max_epochs=3)
        torch.manual_seed(0)
        model = build_model(model_config("csc_lstm", "key", 2, dropout=cfg.dropout))
        train_model(model, data.subset(tr), data.subset(va), cfg, progress=False)
        weights.append(model.state_dict())
    for k in weights[0]:
        assert torch.equal(weights[0][k], weights[1][k]), k


def _bag_with(path, episodes, labels):
    """episodes: {episode: list of (step, state, final)}; labels: list of (episode, length, value, labeller)."""
    with BagWriter(path) as bag:
        t = 1
        for e, steps in episodes.items():
            for step, state, final in steps:
                bag.write_dict("/nmrm/observation", "nmrm_msgs/msg/EnvObservation", {
                    "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "task": "key",
                    "episode": e, "step": step, "state": state, "terminated": False, "truncated": final}, t)
                t += 1
        for e, length, value, who in labels:
            bag.write_dict("/nmrm/trajectory_return", "nmrm_msgs/msg/TrajectoryReturn", {
                "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "task": "key",
                "episode": e, "length": length, "return_value": value, "labeller": who}, t)
            t += 1
    return path


def _steps(n, final=True):
    return [(t, [0.1 * (t % 10), 0.5], final and t == n) for t in range(n + 1)]


def test_bag_validation_counts_and_labels(tmp_path):
    episodes = {
        0: _steps(4),                                   # good
        1: [s for s in _steps(4) if s[0] != 2],         # missing step
        2: _steps(4) + [(1, [0.9, 0.9], False)],        # conflicting duplicate
        3: _steps(4) + [(1, [0.1, 0.5], False)],        # identical duplicate: fine
        4: _steps(4, final=False),                      # no final observation
        5: [(t, [0.1, 0.2, 0.3], t == 4) for t in range(5)],  # wrong state size
        6: _steps(4),                                   # no label
        7: _steps(4),                                   # label length mismatch
    }
    labels = [(e, 4, float(e), "oracle/key") for e in (0, 1, 2, 3, 4, 5)] + [(7, 3, 7.0, "oracle/key")]
    path = _bag_with(tmp_path / "v", episodes, labels)
    ds, report = load_bag_dataset([path])
    assert ds.meta["episodes"] == [0, 3] and report.episodes_seen == 8
    assert dict(report.skipped) == {"missing_steps": 1, "conflicting_duplicates": 1,
                                    "no_final_observation": 1, "wrong_state_size": 1, "no_label": 1,
                                    "label_length_mismatch": 1}


def test_labels_only_bag_and_choosing_a_labeller(tmp_path):
    rec = _bag_with(tmp_path / "rec", {0: _steps(4), 1: _steps(4)}, [(0, 4, 1.0, "oracle/key")])
    people = _bag_with(tmp_path / "people", {}, [(0, 4, 2.0, "alice"), (1, 4, 3.0, "alice")])
    with pytest.raises(BagError, match="several labellers"):
        load_bag_dataset([rec, people])
    ds, report = load_bag_dataset([rec, people], labeller="alice")
    assert ds.returns.tolist() == [2.0, 3.0] and report.labellers == {"alice": 2}
    ds, report = load_bag_dataset([rec, people], labeller="oracle/key")
    assert ds.returns.tolist() == [1.0] and report.skipped == {"no_label": 1}
    only_people = load_bag_dataset([rec, _bag_with(tmp_path / "p2", {}, [(1, 4, 5.0, "bob")])])[0]
    assert only_people.returns.tolist() == [1.0, 5.0]


def test_replay_at_recorded_timing(capture, tmp_path):
    """rate 2 replays a 1.01 s recording (101 observations 10 ms apart) in about 0.5 s, in order.
    The window is timed from the first arrival seen, so a late first delivery (a loaded machine:
    36 ms seen, two test workers) shortens it by that much: at rate 10 (0.1 s) the lower bound of
    0.07 s failed once for that reason; at rate 2 the same delay is under a tenth of the window."""
    ds = generate_screened("timer", 1, seed=0)
    path = write_dataset_bag(ds, tmp_path / "bag", include_oracle=False)
    rp = start("replay", bag=str(path), rate=2.0, topics="['/nmrm/observation']")
    assert capture.spin_until(lambda: len(capture.msgs["observation"]) >= 1, 30)
    t0 = time.monotonic()
    assert capture.spin_until(lambda: len(capture.msgs["observation"]) >= 101, 30)
    elapsed = time.monotonic() - t0
    code, log = finish(rp)
    assert code == 0, log
    assert 0.35 < elapsed < 2.0, elapsed
    assert [m.step for m in capture.msgs["observation"]] == list(range(101))
    assert capture.msgs["action"] == [] and capture.msgs["label"] == []  # filtered out


def test_a_recording_of_nothing_leaves_no_bag(ros_domain, tmp_path):
    """A recorder stopped before any message came (the rest of a launch failed at start) removes
    the bag it created, so the same command can run again; one with messages keeps its bag."""
    out = tmp_path / "nothing"
    rec = start("recorder", output=str(out), observation_wait=0.0)
    time.sleep(2.0)
    rec.send_signal(signal.SIGINT)
    code, log = finish(rec)
    assert code == 0 and "recorded nothing: removed the empty bag" in log, log
    assert not out.exists()
