"""LeRobot v3.0 datasets out of and into bags: the files LeRobot reads (checked with pyarrow and
PyAV, the libraries LeRobot reads them with), the learnt reward column, the round trip bag ->
LeRobot -> bag (states, actions, frames within codec loss, labels, comparisons, provenance), and
one-line errors that leave nothing half-written."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from nmrm_ros.bags.episodes import load_bag_dataset, write_dataset_bag
from nmrm_ros.bags.reader import iter_decoded
from nmrm_ros.bags.writer import BagWriter
from nmrm_ros.datasets import generate_screened
from nmrm_ros.lerobot import LeRobotError, export_lerobot, import_lerobot
from nmrm_ros.lerobot.video import read_frames
from nmrm_ros.mil import OnlineRewardModel, load_train_config
from nmrm_ros.mil.pipeline import fit
from nmrm_ros.tasks.frames import encode_frame, frame_id
from nmrm_ros.testing.graph import executable

EPISODES = 6
FIXTURES = Path(__file__).parent / "fixtures"


def _picture(episode: int, step: int) -> np.ndarray:
    """A 48x64 frame that says which step it shows (smooth, so the codec keeps it)."""
    y, x = np.mgrid[0:48, 0:64]
    rgb = np.stack([x * 3 + step % 40, y * 4 + episode * 10, np.full_like(x, 128)], -1)
    return rgb.astype(np.uint8)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A Key recording of 6 episodes (actions, oracle labels, comparisons by bob), a labels bag of
    alice's, a bag of rendered frames, and a 1-epoch model."""
    root = tmp_path_factory.mktemp("lerobot")
    ds = generate_screened("key", EPISODES, seed=3)
    ds.preferences = np.array([[0, 1, 1.0], [2, 3, 0.0], [4, 5, 0.5]])
    write_dataset_bag(ds, root / "rec", preference_labeller="bob")
    with BagWriter(root / "alice") as bag:
        for i in range(EPISODES):
            bag.write_dict("/nmrm/trajectory_return", "nmrm_msgs/msg/TrajectoryReturn", {
                "header": {"stamp": {"sec": 1000 + i, "nanosec": 5}, "frame_id": ""}, "task": "key",
                "episode": i, "length": int(ds.lengths[i]), "return_value": float(i), "labeller": "alice"},
                10**9 * (1000 + i))
    with BagWriter(root / "frames") as bag:
        t = 10**18
        for i in range(EPISODES):
            for step in range(int(ds.lengths[i]) + 1):
                bag.write_dict("/nmrm/frame", "sensor_msgs/msg/CompressedImage", {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": frame_id(i, step)},
                    "format": "png", "data": encode_frame(_picture(i, step), fmt="png")}, t)
                t += 1000
    model = fit(ds, "csc_lstm", load_train_config("key", max_epochs=1, seed=0), out=root / "model",
                progress=False).checkpoint
    return {"root": root, "ds": ds, "bags": [root / "rec", root / "alice", root / "frames"], "model": model}


@pytest.fixture(scope="module")
def exported(recording):
    out = recording["root"] / "key_lerobot"
    report = export_lerobot(recording["bags"], out, checkpoint=recording["model"], fps=10)
    return out, report


def test_the_export_is_a_lerobot_v3_dataset(recording, exported):
    out, report = exported
    ds = recording["ds"]
    n = int(ds.lengths.sum())
    assert (report.episodes, report.frames, report.labels, report.comparisons) == (EPISODES, n, 2 * EPISODES, 3)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (EPISODES, n, 1)
    assert info["splits"] == {"train": f"0:{EPISODES}"}
    features = info["features"]
    assert list(features)[-5:] == ["timestamp", "frame_index", "episode_index", "index", "task_index"]
    assert features["observation.state"]["shape"] == [2] and features["next.reward"]["shape"] == [1]
    camera = features["observation.images.render"]
    assert camera["dtype"] == "video" and camera["shape"] == [48, 64, 3]
    assert camera["info"]["video.codec"] == "h264" and camera["info"]["video.pix_fmt"] == "yuv420p"
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    assert data.schema.field("observation.state").type == pa.list_(pa.float32(), 2)  # fixed-size list
    assert data.schema.field("action").type == pa.float32()  # shape (1,): a scalar column
    assert data.schema.field("next.done").type == pa.bool_()
    assert data.column("index").to_pylist() == list(range(n))
    # the learnt rewards are the served model's, step by step from each episode's start
    stepper = OnlineRewardModel.from_checkpoint(recording["model"])
    first = int(ds.lengths[0])
    np.testing.assert_allclose(data.column("next.reward").to_numpy()[:first],
                               stepper.episode_rewards(ds.states[0, :first].astype(np.float64)), rtol=1e-5, atol=1e-6)
    assert data.column("next.done").to_pylist()[first - 1:first + 1] == [True, False]
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["length"] for e in episodes] == ds.lengths.tolist()
    assert episodes[1]["dataset_from_index"] == first
    assert episodes[1]["videos/observation.images.render/from_timestamp"] == pytest.approx(first / 10)
    assert {"stats/observation.state/q99", "stats/observation.images.render/mean", "tasks"} <= set(episodes[0])
    stats = json.loads((out / "meta/stats.json").read_text())
    assert set(stats["observation.state"]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
    assert stats["observation.state"]["count"] == [n]
    assert np.asarray(stats["observation.images.render"]["mean"]).shape == (3, 1, 1)
    tasks = pq.read_table(out / "meta/tasks.parquet")
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]  # pd.read_parquet's index
    assert "key" in tasks.column("task")[0].as_py().lower() or tasks.column("task")[0].as_py()
    video = list(read_frames(out / "videos/observation.images.render/chunk-000/file-000.mp4"))
    assert len(video) == n and video[first][0] == pytest.approx(first / 10)  # constant frame rate


def test_bag_to_lerobot_to_bag_keeps_everything(recording, exported, tmp_path):
    out, _ = exported
    back = tmp_path / "back"
    report = import_lerobot(out, back)
    ds = recording["ds"]
    assert (report.episodes, report.labels, report.comparisons) == (EPISODES, 2 * EPISODES, 3)
    for labeller in ("oracle/key", "alice", "bob"):  # bob only compared
        a, _ = load_bag_dataset(recording["bags"], labeller=labeller)
        b, _ = load_bag_dataset([back], labeller=labeller)
        for name in ("states", "final_states", "lengths", "returns", "preferences"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert a.meta["labels"] == b.meta["labels"]
        assert a.meta.get("comparisons") == b.meta.get("comparisons")
    actions, frames = {}, {}
    for topic, type_name, _, m in iter_decoded(back):
        if type_name == "nmrm_msgs/msg/AgentAction":
            actions[(m.episode, m.step)] = m.action[0]
        elif type_name == "sensor_msgs/msg/CompressedImage":
            frames[m.header.frame_id] = m
    assert all(actions[(i, t)] == ds.actions[i, t] for i in range(EPISODES) for t in range(ds.lengths[i]))
    from PIL import Image
    import io

    errors = []
    for i in range(EPISODES):
        for t in range(int(ds.lengths[i])):
            got = np.asarray(Image.open(io.BytesIO(frames[frame_id(i, t)].data)).convert("RGB"), np.float64)
            errors.append(np.abs(got - _picture(i, t)).mean())
    assert max(errors) < 4.0, max(errors)  # H.264 (crf 23) then JPEG (quality 90): mean error per pixel, of 255


def test_anyones_dataset_ends_at_its_last_frame_with_the_task_given(exported, tmp_path):
    out, _ = exported
    theirs = tmp_path / "theirs"
    import shutil

    shutil.copytree(out, theirs)
    shutil.rmtree(theirs / "meta/nmrm")
    report = import_lerobot(theirs, tmp_path / "b1", task="key", episodes="0:3,5", label_key="next.reward",
                            camera="")
    assert (report.episodes, report.labels, report.frames) == (4, 4, 0)
    ds, _ = load_bag_dataset([tmp_path / "b1"])
    data = pq.read_table(theirs / "data/chunk-000/file-000.parquet")
    first = ds.lengths[0] + 1  # the last frame is the final observation
    np.testing.assert_allclose(ds.states[0, :first - 1], np.asarray(data.column("observation.state").to_pylist()[:first - 1]))
    np.testing.assert_allclose(ds.returns[0], data.column("next.reward").to_numpy()[:first].sum(), rtol=1e-6)


def test_anyones_dataset_is_a_task_of_its_own_labelled_modelled_and_exported_with_its_reward(recording, tmp_path):
    """Without --task, anyone's dataset is the task `lerobot:<dir>` (TaskInfo from its metadata, no
    environment): imported, labelled by a labeller's bag, trained on, and exported with
    next.reward = the learnt r'_t. What needs an environment says so in one line."""
    import shutil

    from nmrm_ros.mil.checkpoint import load_checkpoint
    from nmrm_ros.tasks import make_env, task_info

    ds = generate_screened("key", 12, seed=5)
    write_dataset_bag(ds, tmp_path / "rec")
    theirs = tmp_path / "theirs"
    export_lerobot([tmp_path / "rec"], theirs, fps=10)
    shutil.rmtree(theirs / "meta/nmrm")
    report = import_lerobot(theirs, tmp_path / "bag", label_key="next.done")
    task = f"lerobot:{theirs.resolve()}"
    assert report.task == task and report.episodes == 12 and report.labels == 12
    info = task_info(task)
    assert (info.state_size, info.discrete, info.action_size) == (2, False, 1)
    assert info.episode_length == int(ds.lengths.max()) - 1 and info.instruction  # our export: L frames, s_L aside
    with pytest.raises(ValueError, match="recorded LeRobot dataset: it has no environment"):
        make_env(task)
    for bad, match in ((f"{task},state=nope", "no state feature 'nope'"), (f"{task},max_steps=5", "not max_steps"),
                       ("lerobot:" + str(tmp_path / "nowhere"), "not a directory"), (f"{task},xy=0/2", "xy=0/2")):
        with pytest.raises(ValueError, match=match):
            task_info(bad)
    data, _ = load_bag_dataset([tmp_path / "bag"])
    assert data.returns.tolist() == [1.0] * 12  # next.done: 1 on each episode's last frame
    labels = tmp_path / "labels"
    with BagWriter(labels) as bag:
        for i in range(12):
            bag.write_dict("/nmrm/trajectory_return", "nmrm_msgs/msg/TrajectoryReturn", {
                "header": {"stamp": {"sec": 2000 + i, "nanosec": 0}, "frame_id": ""}, "task": task, "episode": i,
                "length": int(data.lengths[i]), "return_value": float(ds.returns[i]), "labeller": "dana"},
                10**9 * (2000 + i))
    res = subprocess.run([executable("nmrm"), "train", "--bag", str(tmp_path / "bag"), "--bag", str(labels),
                          "--out", str(tmp_path / "model"), "--epochs", "1", "--labeller", "dana"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    checkpoint = tmp_path / "model.pt"
    assert load_checkpoint(checkpoint)[1].task == task
    back = tmp_path / "back"
    export_lerobot([tmp_path / "bag", labels], back, checkpoint=checkpoint, fps=10)
    table = pq.read_table(back / "data/chunk-000/file-000.parquet")
    model = OnlineRewardModel.from_checkpoint(checkpoint)
    first = table.filter(pa.compute.equal(table.column("episode_index"), 0))
    expected = [model.step(np.asarray(s, np.float32))[0] for s in first.column("observation.state").to_pylist()]
    np.testing.assert_allclose(first.column("next.reward").to_numpy(), expected, atol=1e-5)
    info = json.loads((back / "meta/nmrm/info.json").read_text())
    assert info["task"] == task
    # our export of a dataset task comes back as a task of its own dataset (the first may be gone)
    again = import_lerobot(back, tmp_path / "again")
    assert again.task == f"lerobot:{back.resolve()}" and again.labels == 24  # dana's and next.done's
    res = subprocess.run([executable("nmrm"), "check", "--checkpoint", str(checkpoint)], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "no environment" in res.stderr, res.stderr
    bare = import_lerobot(theirs, tmp_path / "bare", action_key=None)  # --action ''
    assert bare.task.endswith(",action=") and task_info(bare.task).action_size == 0


def test_a_dataset_written_by_lerobot_itself_comes_in(tmp_path):
    """tests/fixtures/lerobot_v30_small: written by LeRobot 0.4.4's own LeRobotDataset (bench/lerobot_fixture.py;
    AV1 video, LeRobot's statistics) in a venv of its own."""
    from nmrm_ros.lerobot.format import aggregate_stats, column_values, feature_stats

    root = FIXTURES / "lerobot_v30_small"
    report = import_lerobot(root, tmp_path / "bag", task="key", label_key="next.reward")
    assert (report.episodes, report.steps, report.frames, report.labels) == (3, 33, 36, 3)
    ds, _ = load_bag_dataset([tmp_path / "bag"])
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    np.testing.assert_array_equal(ds.lengths, [11, 8, 14])
    np.testing.assert_array_equal(ds.returns, [1.0, 1.0, 1.0])  # next.reward is 1 on each episode's last frame
    state = column_values(data, "observation.state", 2)
    np.testing.assert_array_equal(ds.states[1, :8], state[12:20])
    np.testing.assert_array_equal(ds.final_states[1], state[20])
    # our statistics are LeRobot's (the quantiles: exact here, from its histogram there)
    theirs = json.loads((root / "meta/stats.json").read_text())["observation.state"]
    episode = data.column("episode_index").to_numpy()
    mine = aggregate_stats([feature_stats(state[episode == e]) for e in range(3)])
    for name in ("min", "max", "mean", "std", "count"):
        np.testing.assert_allclose(mine[name], theirs[name], rtol=1e-6, err_msg=name)
    np.testing.assert_allclose(mine["q50"], theirs["q50"], atol=0.05)


def test_bad_datasets_and_options_are_one_line_errors_and_leave_nothing(exported, recording, tmp_path):
    out, _ = exported
    import shutil

    with pytest.raises(LeRobotError, match="exists"):
        export_lerobot(recording["bags"], out)
    old = tmp_path / "old"
    shutil.copytree(out, old)
    info = json.loads((old / "meta/info.json").read_text())
    (old / "meta/info.json").write_text(json.dumps({**info, "codebase_version": "v2.1"}))
    with pytest.raises(LeRobotError, match="format 'v2.1'.*convert_dataset_v21_to_v30"):
        import_lerobot(old, tmp_path / "b")
    (old / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(LeRobotError, match="no state feature 'observation.joints'"):
        import_lerobot(old, tmp_path / "b", state_key="observation.joints")
    with pytest.raises(LeRobotError, match="no episode 99"):
        import_lerobot(old, tmp_path / "b", episodes="99")
    (old / "data/chunk-000/file-000.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(LeRobotError, match="file-000.parquet: not a readable parquet file"):
        import_lerobot(old, tmp_path / "b")
    shutil.copy(out / "data/chunk-000/file-000.parquet", old / "data/chunk-000/file-000.parquet")
    (old / "videos/observation.images.render/chunk-000/file-000.mp4").write_bytes(b"\x00" * 100)
    with pytest.raises(LeRobotError, match="file-000.mp4: not a readable video"):
        import_lerobot(old, tmp_path / "b")
    with pytest.raises(LeRobotError, match="video codec must be one of h264, av1"):
        export_lerobot(recording["bags"], tmp_path / "x", codec="vp9")
    with pytest.raises(LeRobotError, match="episode 0 of task key .* is in both .*rec and .*rec2: export the "
                                           "recordings separately"):
        shutil.copytree(recording["bags"][0], tmp_path / "rec2")
        export_lerobot([recording["bags"][0], tmp_path / "rec2"], tmp_path / "x")
    shutil.rmtree(tmp_path / "rec2")
    # a label column with a missing value: that episode stays unlabelled, the others are labelled
    gappy = tmp_path / "gappy"
    shutil.copytree(out, gappy)
    shutil.rmtree(gappy / "meta/nmrm")
    data = pq.read_table(gappy / "data/chunk-000/file-000.parquet")
    reward = data.column("next.reward").to_numpy().copy()
    reward[3] = np.nan  # a step of episode 0
    i = data.column_names.index("next.reward")
    pq.write_table(data.set_column(i, "next.reward", pa.array(reward, pa.float32())),
                   gappy / "data/chunk-000/file-000.parquet")
    report = import_lerobot(gappy, tmp_path / "g", task="key", label_key="next.reward", camera="")
    assert (report.labels, report.unlabelled) == (EPISODES - 1, 1) and "1 episodes left unlabelled" in str(report)
    assert not (tmp_path / "b").exists() and not (tmp_path / "x").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]


def test_the_commands(exported, recording, tmp_path):
    out = tmp_path / "cli"
    res = subprocess.run([executable("nmrm"), "export", "lerobot", "--bag", str(recording["bags"][0]),
                          "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"wrote {out}: {EPISODES} episodes" in res.stdout and "camera: none in the bags" in res.stdout
    res = subprocess.run([executable("nmrm"), "import", "lerobot", str(out), "--out", str(tmp_path / "bag")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and f"{EPISODES} episodes of task key" in res.stdout, res.stderr
    res = subprocess.run([executable("nmrm"), "import", "lerobot", str(tmp_path / "bag"), "--out", str(tmp_path / "b2")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "no meta/info.json" in res.stderr, res.stderr


def test_people_label_an_imported_lerobot_dataset_on_the_page(ros_domain, tmp_path):
    """LeRobot's own dataset -> `nmrm import lerobot` -> label_bag.launch.yaml (real replay and
    labeller_web processes): the page lists its episodes, serves their camera frames, takes a
    label, and the labels bag joins the imported bag for training."""
    import re
    import signal
    import urllib.request

    from nmrm_ros.ros.ament_paths import require_share_dir
    from nmrm_ros.testing.graph import OutputLines

    task = import_lerobot(FIXTURES / "lerobot_v30_small", tmp_path / "bag").task  # the dataset is the task
    assert task == f"lerobot:{FIXTURES / 'lerobot_v30_small'}"
    launch_file = require_share_dir("nmrm_ros") / "launch_scripts" / "label_bag.launch.yaml"
    proc = subprocess.Popen([executable("nmrm"), "launch", str(launch_file), f"bag:={tmp_path / 'bag'}", f"task:={task}",
                             "port:=0", f"labels_dir:={tmp_path / 'labels'}", "person:=carol"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = OutputLines(proc)
    try:
        url = re.search(r"(http://127\.0\.0\.1:\d+)/\?token=([\w-]+)", out.wait_for("labelling page: http"))
        base, token = url.group(1), url.group(2)
        out.wait_for("episode 2 (14 steps) waits for a label")
        queue = json.loads(urllib.request.urlopen(f"{base}/api/queue?token={token}", timeout=10).read())
        assert [e["episode"] for e in queue["episodes"]] == [0, 1, 2]
        info = json.loads(urllib.request.urlopen(f"{base}/api/info?token={token}", timeout=10).read())
        assert info["instruction"] == "push the block to the line"  # the dataset's task text
        # frames travel on their own topic: they may arrive after the episode is offered (the
        # page asks again while its final step's frame is missing)
        deadline = time.monotonic() + 10
        while 3 not in json.loads(urllib.request.urlopen(f"{base}/api/episode/1/frames?token={token}",
                                                         timeout=10).read())["frames"]:
            assert time.monotonic() < deadline, "episode 1's frame 3 never arrived"
            time.sleep(0.2)
        with pytest.raises(urllib.error.HTTPError, match="404"):  # no such episode: not an empty list
            urllib.request.urlopen(f"{base}/api/episode/99/frames?token={token}", timeout=10)
        frame = urllib.request.urlopen(f"{base}/api/episode/1/frame/3?token={token}", timeout=10)
        assert frame.headers["Content-Type"] == "image/jpeg" and len(frame.read()) > 100
        request = urllib.request.Request(f"{base}/api/label", data=json.dumps({"episode": 1, "return": 4.0}).encode(),
                                         headers={"Content-Type": "application/json", "X-Token": token,
                                                  "Origin": base}, method="POST")
        assert json.loads(urllib.request.urlopen(request, timeout=10).read())["return"] == 4.0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    labels = next(p for p in (tmp_path / "labels").iterdir() if p.name.startswith("person_carol"))
    ds, report = load_bag_dataset([tmp_path / "bag", labels])
    assert report.labellers == {"person/carol": 1} and ds.returns.tolist() == [4.0] and ds.lengths.tolist() == [8]
