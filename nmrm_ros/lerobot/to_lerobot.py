"""Bags -> a LeRobot v3.0 dataset (`nmrm export lerobot`).

    report = export_lerobot(["bags/key_2000"], "out/key_lerobot", checkpoint="runs/key.pt")

Per frame (one per step t = 0..L-1 of each episode, LeRobot's convention: the observation and the
action taken on it): `observation.state` (s_t), `action` (a_t; a discrete action as its index),
`next.reward` (r'_t of the learnt model, with `checkpoint`), `observation.reward_model_state`
(the state the model serves an agent beside s_t, h'_{t+1}, with `checkpoint`), `next.done`
(true on an episode's last frame), `observation.images.render` (the rendered frames of
`nmrm/frame`, as video, when the bags hold one for every step) and LeRobot's own columns. The
task text is the task's instruction (what a person labelling it judges). In `meta/nmrm/`:
`info.json` (task, checkpoint, sources), `episodes.parquet` (each episode's source and episode
id in the bags and its final observation s_L), `labels.parquet` (every return label with its
labeller, time and whether it is gold) and `comparisons.parquet` (every comparison).

Episodes are checked as `load_bag_dataset` checks them (steps 0..L, the last one final, states of
the task's size): the others are skipped and counted. Nothing is written unless all of it is:
the dataset is built in a directory beside `out` and renamed at the end.
"""

from __future__ import annotations

import io
import shutil
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .format import (CODEBASE_VERSION, CHUNKS_SIZE, DATA_FILE_MB, DATA_PATH, DEFAULT_FEATURES, EPISODES_PATH,
                     INFO_PATH, NMRM_DIR, STATS_PATH, VIDEO_FILE_MB, VIDEO_PATH, LeRobotError, aggregate_stats,
                     arrow_column, feature_stats, image_stats, next_file, stats_json, temporary_sibling,
                     write_json, write_tasks)
from ..bags.observation_images import BagImages
from .video import VideoWriter, video_info

CAMERA = "observation.images.render"
STATE = "observation.state"
SERVED = "observation.reward_model_state"


@dataclass
class ExportReport:
    out: str = ""
    episodes: int = 0
    frames: int = 0
    labels: int = 0
    comparisons: int = 0
    skipped: Counter = field(default_factory=Counter)
    camera: str = ""     # what happened to the rendered frames
    seconds: float = 0.0
    bytes: int = 0

    def __str__(self) -> str:
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items())) or "none"
        return (f"wrote {self.out}: {self.episodes} episodes, {self.frames} frames, {self.labels} return labels, "
                f"{self.comparisons} comparisons; skipped: {skipped}; camera: {self.camera}; "
                f"{self.bytes / 1e6:.1f} MB in {self.seconds:.1f} s")


@dataclass
class _Episode:
    source: str
    task: str
    episode: int
    states: dict = field(default_factory=dict)   # step -> (state, terminated, truncated, log time ns); as read:
                                                 # the EnvObservation in place of the state (`_usable` decodes it)
    actions: dict = field(default_factory=dict)  # step -> action vector
    frames: dict = field(default_factory=dict)   # step -> (format, bytes)
    images: BagImages | None = None              # its recording's observation images (an image task's pixels)


def _read_bags(paths: list):
    """Episodes by (source, task, episode), return labels and comparisons of every bag. A bag with
    observations is a recording; actions and frames in other bags join the recording's episode of
    the same (source, episode), as labels-only bags join in `load_bag_dataset`. Two recordings
    holding one episode are an error (they would be merged)."""
    from ..bags.episodes import T_ACT, T_OBS, T_PREF, T_RET
    from ..bags.reader import iter_decoded
    from ..bags.schemas import split_topic
    from ..tasks.frames import parse_frame_id

    recordings, others = [], []
    labels, comparisons = [], []
    for path in paths:
        episodes: dict = {}
        actions, frames, images = defaultdict(dict), defaultdict(dict), BagImages()
        for topic, type_name, log_ns, m in iter_decoded(path):
            try:
                source = split_topic(topic)[0]
            except ValueError:
                continue
            if images.take(topic, type_name, m):
                continue
            if type_name == T_OBS:
                key = (source, m.task, int(m.episode))
                ep = episodes.setdefault(key, _Episode(*key))
                ep.states.setdefault(int(m.step), (m, bool(m.terminated), bool(m.truncated), int(log_ns)))
            elif type_name == T_ACT:
                actions[(source, int(m.episode))][int(m.step)] = np.asarray(m.action, np.float32)
            elif type_name == "sensor_msgs/msg/CompressedImage":
                named = parse_frame_id(m.header.frame_id)
                if named is not None:
                    frames[(source, named[0])][named[1]] = (m.format, bytes(m.data))
            elif type_name == T_RET:
                labels.append((source, m))
            elif type_name == T_PREF:
                comparisons.append((source, m))
        for ep in episodes.values():
            ep.images = images
        (recordings if episodes else others).append((path, episodes, actions, frames))
    owner, episodes = {}, {}
    for path, eps, actions, frames in recordings:
        for key, ep in eps.items():
            if key in owner:
                raise LeRobotError(f"episode {key[2]} of task {key[1]} (source {key[0] or '/'}) is in both "
                                   f"{owner[key]} and {path}: export the recordings separately")
            owner[key] = path
            ep.actions = actions.get((key[0], key[2]), {})
            ep.frames = frames.get((key[0], key[2]), {})
            episodes[key] = ep
    by_id = defaultdict(list)
    for key in episodes:
        by_id[(key[0], key[2])].append(key)
    for path, _, actions, frames in others:
        for table, what in ((actions, "actions"), (frames, "frames")):
            for (source, e), steps in table.items():
                keys = by_id.get((source, e), [])
                if len(keys) > 1:
                    raise LeRobotError(f"{path}: {what} of episode {e} (source {source or '/'}) would join "
                                       f"episodes of several tasks; export one task's bags at a time")
                for key in keys:
                    getattr(episodes[key], what).update(steps)
    return episodes, labels, comparisons


def _usable(ep: _Episode, info) -> str:
    """'' if the episode can be exported, else the reason (load_bag_dataset's names); its states
    made whole (an image task's pixels put back from its observation images)."""
    state_size = info.state_size
    try:
        ep.states = {t: (ep.images.whole_state(ep.source, m, info), *rest) for t, (m, *rest) in ep.states.items()}
    except ValueError:
        return "missing_image"
    steps = sorted(ep.states)
    length = steps[-1]
    if steps != list(range(length + 1)):
        return "missing_steps"
    flags = [ep.states[t][1] or ep.states[t][2] for t in steps]
    if length == 0 or not flags[-1] or any(flags[:-1]):
        return "no_final_observation"
    if any(ep.states[t][0].shape != (state_size,) or not np.all(np.isfinite(ep.states[t][0])) for t in steps):
        return "wrong_state_size"
    return ""


def _decode(fmt_data: tuple, where: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(fmt_data[1])) as image:
            return np.asarray(image.convert("RGB"))
    except (UnidentifiedImageError, OSError) as exc:
        raise LeRobotError(f"{where}: a rendered frame that is not an image ({exc})") from None


def _frames_of_images(chosen: list, lengths: list, image_shape: tuple) -> bool:
    """On an image task, an episode without rendered frames gets the images the model saw as its
    frames (each pixel a block, as the labelling page shows them: `frames.image_state_frame`);
    whether any did."""
    if not image_shape:
        return False
    from ..tasks.frames import encode_frame, image_state_frame

    drawn = False
    for ep, n in zip(chosen, lengths):
        if not ep.frames:
            shown = [image_state_frame(ep.states[t][0], image_shape) for t in range(n)]
            ep.frames = {t: ("png", encode_frame(f, width=f.shape[1], fmt="png")) for t, f in enumerate(shown)}
            drawn = True
    return drawn


def _fps(episodes: list) -> int:
    """Steps per second of the recording: the median time between an episode's observations."""
    gaps = []
    for ep in episodes:
        times = [ep.states[t][3] for t in sorted(ep.states)]
        gaps.extend(np.diff(times).tolist())
    gaps = [g for g in gaps if g > 0]
    return max(1, int(round(1e9 / float(np.median(gaps))))) if gaps else 10


def export_lerobot(bags: list, out: str | Path, checkpoint: str | Path | None = None, task: str | None = None,
                   fps: int | None = None, codec: str = "h264", served: str | None = None,
                   progress: bool = False) -> ExportReport:
    """Write the episodes of `bags` (recordings and labels-only bags) as a LeRobot v3.0 dataset
    at `out` (which must not exist); see the module docstring. task: the task to export where the
    bags hold several; fps: frames per second (default: the recording's step rate); codec: of the
    camera's video ("h264" | "av1"); served: what of the model's state to export (default the
    checkpoint's). LeRobotError (one line) for what cannot be exported."""
    from ..tasks import task_info

    t0 = time.perf_counter()
    out = Path(out)
    if out.exists():
        raise LeRobotError(f"{out} exists: give a new directory (nothing is overwritten)")
    if fps is not None and int(fps) < 1:
        raise LeRobotError(f"fps must be at least 1, got {fps}")
    from .video import CODECS

    if codec not in CODECS:
        raise LeRobotError(f"video codec must be one of {', '.join(CODECS)}, got {codec!r}")
    model = None
    if checkpoint is not None:  # before the bags are read: a wrong checkpoint costs nothing
        from ..mil import CheckpointError, OnlineRewardModel

        try:
            model = OnlineRewardModel.from_checkpoint(checkpoint, task=task, served=served)
        except (CheckpointError, ValueError, OSError) as exc:
            raise LeRobotError(f"checkpoint {checkpoint}: {exc}") from None
    episodes, labels, comparisons = _read_bags([Path(b) for b in bags])
    if not episodes:
        raise LeRobotError(f"no EnvObservation messages in {', '.join(map(str, bags))}")
    tasks = sorted({k[1] for k in episodes})
    if task is None:
        if len(tasks) > 1:
            raise LeRobotError(f"the bags hold episodes of several tasks {tasks}; choose one (--task)")
        task = tasks[0]
    elif task not in tasks:
        raise LeRobotError(f"the bags hold no episode of task {task!r} (they hold {tasks})")
    info = task_info(task)
    report = ExportReport(out=str(out))
    chosen = []
    for key in sorted(k for k in episodes if k[1] == task):
        reason = _usable(episodes[key], info)
        if reason:
            report.skipped[reason] += 1
        else:
            chosen.append(episodes[key])
    if not chosen:
        raise LeRobotError(f"no usable episode of task {task!r} (skipped: {dict(report.skipped)})")
    fps = int(fps) if fps is not None else _fps(chosen)
    lengths = [max(ep.states) for ep in chosen]
    with_actions = all(all(t in ep.actions for t in range(n)) for ep, n in zip(chosen, lengths))
    action_size = len(chosen[0].actions[0]) if with_actions else 0
    if with_actions and any(len(ep.actions[t]) != action_size for ep, n in zip(chosen, lengths) for t in range(n)):
        raise LeRobotError("the episodes' actions are not all of one size")
    if not with_actions and any(ep.actions for ep in chosen):
        report.skipped["actions_of_some_steps_missing (no action column)"] += 1
    drawn = _frames_of_images(chosen, lengths, info.image_shape)
    with_frames = all(all(t in ep.frames for t in range(n)) for ep, n in zip(chosen, lengths))
    some_frames = any(ep.frames for ep in chosen)
    report.camera = (f"{CAMERA} ({codec} video{', of the observation images' if drawn else ''})" if with_frames else
                     "none: some exported steps have no rendered frame" if some_frames else "none in the bags")
    if model is not None and (model.task != task or model.input_size != info.state_size):
        raise LeRobotError(f"checkpoint {checkpoint} is a model of task {model.task!r} (states of {model.input_size}); "
                           f"the episodes are of {task!r} (states of {info.state_size})")

    tmp = temporary_sibling(out)
    try:
        tmp.mkdir(parents=True)
        _write(tmp, chosen, lengths, info, task, fps, codec, model, with_actions, action_size, with_frames,
               labels, comparisons, report, progress)
        write_json(tmp / NMRM_DIR / "info.json", {
            "nmrm_ros": __import__("nmrm_ros").__version__, "task": task, "bags": [str(b) for b in bags],
            "checkpoint": None if checkpoint is None else str(checkpoint),
            "served_state": None if model is None else model.served,
            "reward": "next.reward: r'_t of the checkpoint's model (the members' mean), as served online",
            "state": STATE, "action": "action" if with_actions else None,
            "camera": CAMERA if with_frames else None})
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    report.seconds = time.perf_counter() - t0
    report.bytes = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    return report


def _closing(items, current_video):
    """`items`, closing the video `current_video()` returns if the loop over them fails (an open
    PyAV container would otherwise hold its file until garbage collection)."""
    try:
        yield from items
    except BaseException:
        video = current_video()
        if video is not None:
            video.close()
        raise


def _write(root, chosen, lengths, info, task, fps, codec, model, with_actions, action_size, with_frames,
           labels, comparisons, report, progress) -> None:
    """The dataset's files under `root` (export_lerobot's work once the episodes are chosen)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..labelling.agreement import is_gold

    d = info.state_size
    text = info.instruction or task
    features = {STATE: {"dtype": "float32", "shape": [d], "names": None}}
    if with_actions:
        features["action"] = {"dtype": "float32", "shape": [action_size],
                              "names": ["action index"] if info.discrete and action_size == 1 else None}
    if model is not None:
        features["next.reward"] = {"dtype": "float32", "shape": [1], "names": None}
        if model.served_size:
            features[SERVED] = {"dtype": "float32", "shape": [int(model.served_size)], "names": None}
    features["next.done"] = {"dtype": "bool", "shape": [1], "names": None}

    rows = []          # per episode: the meta/episodes row
    episode_stats = []  # per episode: {feature: stats}
    nmrm_rows = {"episode_index": [], "source": [], "episode": [], "terminated": [], "final_state": []}
    index_of = {}
    data_chunk = data_file = 0
    data_tables, data_bytes = [], 0
    bytes_per_frame = 4 * (d + action_size + 2 + (model.served_size if model is not None else 0)) + 44
    video = None
    video_chunk = video_file = 0
    frame_shape = None
    first_video = None
    global_index = 0
    iterator = enumerate(zip(chosen, lengths))
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, total=len(chosen), desc="episodes", unit="ep")

    def flush_data():
        nonlocal data_tables, data_bytes, data_chunk, data_file
        if data_tables:
            path = root / DATA_PATH.format(chunk_index=data_chunk, file_index=data_file)
            path.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(pa.concat_tables(data_tables), path)
            data_chunk, data_file = next_file(data_chunk, data_file)
        data_tables, data_bytes = [], 0

    for e, (ep, n) in _closing(iterator, lambda: video):
        index_of[(ep.source, ep.episode)] = e
        states = np.stack([ep.states[t][0] for t in range(n)])
        cols = {STATE: states}
        if with_actions:
            cols["action"] = np.stack([ep.actions[t] for t in range(n)])
        if model is not None:
            model.reset()
            stepped = [model.step(s.astype(np.float64)) for s in states]
            cols["next.reward"] = np.array([r for r, _ in stepped], np.float32)
            if model.served_size:
                cols[SERVED] = np.stack([np.asarray(h, np.float32) for _, h in stepped])
        cols["next.done"] = np.arange(n) == n - 1
        frame_index = np.arange(n, dtype=np.int64)
        defaults = {"timestamp": (frame_index / fps).astype(np.float32), "frame_index": frame_index,
                    "episode_index": np.full(n, e, np.int64),
                    "index": np.arange(global_index, global_index + n, dtype=np.int64),
                    "task_index": np.zeros(n, np.int64)}
        if data_tables and data_bytes + n * bytes_per_frame >= DATA_FILE_MB * 1e6:
            flush_data()
        row = {"episode_index": e, "tasks": [text], "length": n,
               "data/chunk_index": data_chunk, "data/file_index": data_file,
               "dataset_from_index": global_index, "dataset_to_index": global_index + n}
        table = {}
        for name, spec in {**features, **DEFAULT_FEATURES}.items():
            values = cols.get(name, defaults.get(name))
            table[name] = arrow_column(values, spec["dtype"])
        data_tables.append(pa.table(table))
        data_bytes += n * bytes_per_frame
        stats = {name: feature_stats(np.asarray(cols.get(name, defaults.get(name)), np.float64))
                 for name in {**features, **DEFAULT_FEATURES}}
        if with_frames:
            rgb = np.stack([_decode(ep.frames[t], f"episode {ep.episode} of {ep.source or '/'}, step {t}")
                            for t in range(n)])
            if frame_shape is None:
                frame_shape = rgb.shape[1:]
            elif rgb.shape[1:] != frame_shape:
                raise LeRobotError(f"episode {ep.episode} of {ep.source or '/'}: frames of {rgb.shape[1:]} "
                                   f"where the first were {frame_shape}")
            if video is not None and video.bytes() >= VIDEO_FILE_MB * 1e6:
                video.close()
                video_chunk, video_file = next_file(video_chunk, video_file)
                video = None
            if video is None:
                video = VideoWriter(root / VIDEO_PATH.format(video_key=CAMERA, chunk_index=video_chunk,
                                                             file_index=video_file), fps, codec)
                first_video = first_video or video.path
            start, end = video.add_episode(rgb)
            row.update({f"videos/{CAMERA}/chunk_index": video_chunk, f"videos/{CAMERA}/file_index": video_file,
                        f"videos/{CAMERA}/from_timestamp": start, f"videos/{CAMERA}/to_timestamp": end})
            stats[CAMERA] = image_stats(rgb)
        episode_stats.append(stats)
        for name, st in stats.items():
            for s, v in st.items():
                row[f"stats/{name}/{s}"] = np.asarray(v).tolist()
        row["meta/episodes/chunk_index"], row["meta/episodes/file_index"] = 0, 0
        rows.append(row)
        nmrm_rows["episode_index"].append(e)
        nmrm_rows["source"].append(ep.source)
        nmrm_rows["episode"].append(ep.episode)
        nmrm_rows["terminated"].append(ep.states[n][1])
        nmrm_rows["final_state"].append(ep.states[n][0])
        global_index += n
    flush_data()
    if video is not None:
        video.close()
    if with_frames:
        h, w = video.size if video is not None else frame_shape[:2]
        features[CAMERA] = {"dtype": "video", "shape": [int(h), int(w), 3], "names": ["height", "width", "channels"],
                            "info": video_info(first_video, fps)}

    episodes_path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), episodes_path)
    write_tasks(root, [text])
    totals = {name: aggregate_stats([st[name] for st in episode_stats]) for name in episode_stats[0]}
    write_json(root / STATS_PATH, stats_json(totals))
    write_json(root / INFO_PATH, {
        "codebase_version": CODEBASE_VERSION, "robot_type": None, "total_episodes": len(chosen),
        "total_frames": int(global_index), "total_tasks": 1, "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILE_MB, "video_files_size_in_mb": VIDEO_FILE_MB, "fps": int(fps),
        "splits": {"train": f"0:{len(chosen)}"}, "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if with_frames else None, "features": {**features, **DEFAULT_FEATURES}})

    nmrm = root / NMRM_DIR
    nmrm.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table({
        "episode_index": pa.array(nmrm_rows["episode_index"], pa.int64()),
        "source": pa.array(nmrm_rows["source"], pa.string()),
        "episode": pa.array(nmrm_rows["episode"], pa.int64()),
        "terminated": pa.array(nmrm_rows["terminated"], pa.bool_()),
        "final_state": arrow_column(np.stack(nmrm_rows["final_state"]).reshape(len(chosen), -1), "float32")
        if info.state_size > 1 else pa.array(np.stack(nmrm_rows["final_state"]).reshape(-1))}),
        nmrm / "episodes.parquet")
    label_rows = []
    for source, m in labels:
        e = index_of.get((source, int(m.episode)))
        if e is None or m.task != task:
            report.skipped["label_of_unexported_episode"] += 1
        elif int(m.length) != lengths[e]:
            report.skipped["label_length_mismatch"] += 1
        else:
            label_rows.append({"episode_index": e, "return": float(m.return_value), "labeller": m.labeller,
                               "gold": is_gold(m.labeller),
                               "stamp_ns": int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec)})
    pq.write_table(pa.Table.from_pylist(label_rows, schema=pa.schema([
        ("episode_index", pa.int64()), ("return", pa.float64()), ("labeller", pa.string()), ("gold", pa.bool_()),
        ("stamp_ns", pa.int64())])), nmrm / "labels.parquet")
    report.labels = len(label_rows)
    pair_rows = []
    for source, m in comparisons:
        a = index_of.get((m.source_a or source, int(m.episode_a)))
        b = index_of.get((m.source_b or source, int(m.episode_b)))
        if a is None or b is None or m.task != task:
            report.skipped["comparison_of_unexported_episode"] += 1
        elif (int(m.length_a), int(m.length_b)) != (lengths[a], lengths[b]):
            report.skipped["comparison_length_mismatch"] += 1
        elif int(m.preference) not in (-1, 0, 1):
            report.skipped["comparison_unknown_preference"] += 1
        else:
            pair_rows.append({"episode_index_a": a, "episode_index_b": b, "p": (int(m.preference) + 1) / 2,
                              "labeller": m.labeller,
                              "stamp_ns": int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec)})
    pq.write_table(pa.Table.from_pylist(pair_rows, schema=pa.schema([
        ("episode_index_a", pa.int64()), ("episode_index_b", pa.int64()), ("p", pa.float64()),
        ("labeller", pa.string()), ("stamp_ns", pa.int64())])), nmrm / "comparisons.parquet")
    report.comparisons = len(pair_rows)
    report.episodes, report.frames = len(chosen), int(global_index)
