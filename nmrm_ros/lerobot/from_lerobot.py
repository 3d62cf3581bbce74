"""A LeRobot v3.0 dataset -> a bag (`nmrm import lerobot`): episodes the labelling page plays,
`nmrm train` trains on and the reward model serves.

    report = import_lerobot("datasets/so100_pick", "bags/so100_pick", task="my_pkg.tasks:Pick,...")

Each LeRobot episode of n frames becomes an episode of EnvObservation messages (the state column,
`state_key`), AgentAction messages (`action_key`) and, with a camera (`camera`: a video or image
feature), its frames as `sensor_msgs/CompressedImage` on `nmrm/frame` (JPEG), as env_sim records
them. A dataset we exported (`meta/nmrm/`) comes back as it was: its task, sources, episode ids,
final observations s_L, return labels with their labellers and times, and comparisons. Anyone
else's has no final observation after the last action: its last frame's state is taken as s_L
(L = n - 1 steps; the last frame's action is dropped); its task is the dataset itself,
`lerobot:<root>` (`dataset_task`: no environment), unless a task spec whose state size is the
state column's is given (then episodes can be run and agents trained on its environment). `label_key` (e.g. "next.reward") labels each episode
with the sum of that column over all its frames (the episode's return as LeRobot keeps it: the
last frame's reward included), from labeller "lerobot/<key>".

Nothing is half-written: the bag is written beside `out` and renamed at the end; a missing key, a
dataset of another version, a corrupt parquet or video is a one-line LeRobotError.
"""

from __future__ import annotations

import io
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .format import (NMRM_DIR, LeRobotError, column_values, read_episode_rows, read_info, read_parquet,
                     temporary_sibling, vector_width)
from .video import read_frames


@dataclass
class ImportReport:
    out: str = ""
    task: str = ""
    episodes: int = 0
    steps: int = 0
    frames: int = 0
    labels: int = 0
    comparisons: int = 0
    seconds: float = 0.0
    note: str = ""
    unlabelled: int = 0  # --label: episodes whose label column has a missing or NaN value

    def __str__(self) -> str:
        return (f"wrote {self.out}: {self.episodes} episodes of task {self.task} ({self.steps} steps, "
                f"{self.frames} frames), {self.labels} return labels, {self.comparisons} comparisons in "
                f"{self.seconds:.1f} s" + (f"; {self.unlabelled} episodes left unlabelled (a missing or NaN "
                                           f"value in the label column)" if self.unlabelled else "")
                + (f"; {self.note}" if self.note else ""))


def parse_episodes(text: str | None, total: int) -> list | None:
    """"0:10,15,20:22" -> [0..9, 15, 20, 21] (None: every episode); LeRobotError for nonsense."""
    if text is None or not str(text).strip():
        return None
    out = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            if ":" in part:
                a, b = part.split(":")
                out.extend(range(int(a or 0), int(b) if b else total))
            else:
                out.append(int(part))
        except ValueError:
            raise LeRobotError(f"episodes must be indices and ranges such as 0:10,15, got {text!r}") from None
    bad = [e for e in out if not 0 <= e < total]
    if bad:
        raise LeRobotError(f"the dataset has episodes 0..{total - 1}; no episode {bad[0]}")
    return sorted(set(out))


def _feature(info: dict, key: str, what: str) -> dict:
    spec = info["features"].get(key)
    if spec is None:
        names = ", ".join(k for k in info["features"] if not k.startswith(("timestamp", "frame_index", "index",
                                                                           "episode_index", "task_index")))
        raise LeRobotError(f"the dataset has no {what} feature {key!r} (its features: {names})")
    return spec


def _camera_frames(root: Path, info: dict, camera: str, rows: list, wanted: set) -> dict:
    """{episode_index: {frame_index: encoded JPEG}} of a video or image feature."""
    spec = info["features"][camera]
    fps = float(info["fps"])
    out: dict = {e: {} for e in wanted}
    if spec.get("dtype") == "image":
        return out  # read with the data table (`_image_column`)
    by_file: dict = {}
    for r in rows:
        if int(r["episode_index"]) not in wanted:
            continue
        try:
            key = (int(r[f"videos/{camera}/chunk_index"]), int(r[f"videos/{camera}/file_index"]))
            span = (float(r[f"videos/{camera}/from_timestamp"]), float(r[f"videos/{camera}/to_timestamp"]))
        except KeyError as exc:
            raise LeRobotError(f"meta/episodes has no {exc.args[0]!r} column for camera {camera!r}") from None
        by_file.setdefault(key, []).append((span, int(r["episode_index"]), int(r["length"])))
    template = info.get("video_path") or "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    for (chunk, file), spans in sorted(by_file.items()):
        path = root / template.format(video_key=camera, chunk_index=chunk, file_index=file)
        spans.sort()
        for t, rgb in read_frames(path):
            for (start, end), e, n in spans:
                if start - 0.5 / fps <= t < end - 0.5 / fps:
                    j = int(round((t - start) * fps))
                    if 0 <= j < n:
                        out[e][j] = _jpeg(rgb)
                    break
    return out


def _jpeg(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(rgb, np.uint8), "RGB").save(buf, format="JPEG", quality=90)
    return buf.getvalue()


def _image_column(table, camera: str) -> list:
    """Encoded frames (PNG/JPEG bytes, re-encoded as JPEG) of an image feature, one per row."""
    from PIL import Image, UnidentifiedImageError

    out = []
    for row, cell in enumerate(table.column(camera).to_pylist()):
        data = cell.get("bytes") if isinstance(cell, dict) else None
        if not data:
            raise LeRobotError(f"image feature {camera!r}: a frame without its bytes (images kept as files "
                               f"are not read)")
        try:
            with Image.open(io.BytesIO(data)) as image:
                out.append(_jpeg(np.asarray(image.convert("RGB"))))
        except (UnidentifiedImageError, OSError) as exc:
            raise LeRobotError(f"image feature {camera!r}: frame {row} of a data file is not an image ({exc})") from None
    return out


def import_lerobot(root: str | Path, out: str | Path, task: str | None = None,
                   state_key: str = "observation.state", action_key: str | None = "action",
                   camera: str | None = None, episodes: str | None = None,
                   label_key: str | None = None) -> ImportReport:
    """Write the episodes of the LeRobot v3.0 dataset at `root` into a new bag `out`; see the
    module docstring. camera: the video or image feature whose frames go to `nmrm/frame` (None:
    the first one the dataset has; "" for none); episodes: which ("0:10,15"; None: all)."""
    import json

    from ..tasks import task_info
    from ..tasks.gym_task import LEROBOT_PREFIX

    t0 = time.perf_counter()
    root, out = Path(root), Path(out)
    if out.exists():
        raise LeRobotError(f"{out} exists: give a new bag directory (nothing is overwritten)")
    info = read_info(root)
    ours_path = root / NMRM_DIR / "info.json"
    ours = None
    if ours_path.is_file():
        try:
            ours = json.loads(ours_path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise LeRobotError(f"{ours_path}: not JSON ({exc})") from None
        if not isinstance(ours, dict):
            raise LeRobotError(f"{ours_path}: not a table of nmrm_ros export facts")
    width = vector_width(_feature(info, state_key, "state"), state_key)
    if action_key and action_key not in info["features"]:
        if action_key != "action":  # asked for by name
            _feature(info, action_key, "action")
        action_key = None
    action_width = vector_width(info["features"][action_key], action_key) if action_key else 0
    if label_key:
        vector_width(_feature(info, label_key, "label"), label_key)
    cameras = [k for k, v in info["features"].items() if v.get("dtype") in ("video", "image")]
    if camera is None:
        camera = cameras[0] if cameras else ""
    elif camera and camera not in cameras:
        raise LeRobotError(f"the dataset has no camera {camera!r} (its cameras: {', '.join(cameras) or 'none'})")
    recorded = (ours or {}).get("task")
    if recorded and str(recorded).startswith(LEROBOT_PREFIX):
        recorded = None  # our export of a dataset task: the dataset imported now is the task
    task = task or recorded
    if not task:  # anyone's dataset: the dataset is the task (`dataset_task`)
        from .dataset_task import dataset_task_spec

        task = dataset_task_spec(root, state_key, action_key)
    try:
        size = task_info(task).state_size
    except ValueError as exc:  # an unknown task, a spec that cannot be used
        raise LeRobotError(str(exc)) from None
    if size != width:
        raise LeRobotError(f"task {task!r} has states of {size} values; {state_key!r} has {width}")

    rows = read_episode_rows(root)
    if len(rows) != int(info["total_episodes"]) or [int(r["episode_index"]) for r in rows] != list(range(len(rows))):
        raise LeRobotError(f"meta/episodes lists {len(rows)} episodes, not episodes 0..{int(info['total_episodes']) - 1} "
                           f"as meta/info.json says")
    chosen = parse_episodes(episodes, len(rows))
    wanted = set(range(len(rows))) if chosen is None else set(chosen)
    data_files = sorted((root / "data").glob("*/*.parquet"))
    if not data_files:
        raise LeRobotError(f"{root}: no data/*/*.parquet")
    columns = ["episode_index", "frame_index", state_key] + ([action_key] if action_key else []) + \
        ([label_key] if label_key else []) + ([camera] if camera and info["features"][camera]["dtype"] == "image" else [])
    per_episode: dict = {e: [] for e in wanted}
    for f in data_files:
        table = read_parquet(f)
        missing = [c for c in columns if c not in table.column_names]
        if missing:
            raise LeRobotError(f"{f}: no column {missing[0]!r}")
        eps = table.column("episode_index").to_numpy()
        keep = np.isin(eps, list(wanted))
        if not keep.any():
            continue
        import pyarrow as pa

        table = table.select(columns).filter(pa.array(keep))
        per_episode_table = {
            "e": table.column("episode_index").to_numpy(), "j": table.column("frame_index").to_numpy(),
            "s": column_values(table, state_key, width).astype(np.float32),
            "a": column_values(table, action_key, action_width).astype(np.float32) if action_key else None,
            "g": column_values(table, label_key, 1)[:, 0].astype(np.float64) if label_key else None,
            "img": _image_column(table, camera) if camera in columns else None}
        for e in np.unique(per_episode_table["e"]):
            per_episode[int(e)].append({k: (None if v is None else
                                            ([v[i] for i in np.flatnonzero(per_episode_table["e"] == e)]
                                             if isinstance(v, list) else v[per_episode_table["e"] == e]))
                                        for k, v in per_episode_table.items()})
    frames = _camera_frames(root, info, camera, rows, wanted) if camera else {}
    side = _side_tables(root) if ours else None
    tmp = temporary_sibling(out)
    try:
        report = _write_bag(tmp, out.name, task, rows, per_episode, frames, side, sorted(wanted), label_key,
                            bool(camera))
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    report.out = str(out)
    report.seconds = time.perf_counter() - t0
    if not ours:
        report.note = "not an nmrm_ros export: each episode's last frame is its final observation"
    return report


def _side_tables(root: Path) -> dict:
    """meta/nmrm/*.parquet of a dataset we exported, as Python rows."""
    nmrm = root / NMRM_DIR
    return {name: read_parquet(nmrm / f"{name}.parquet").to_pylist() for name in ("episodes", "labels", "comparisons")}


def _write_bag(path: Path, name: str, task: str, rows: list, per_episode: dict, frames: dict, side: dict | None,
               wanted: list, label_key: str | None, with_camera: bool) -> ImportReport:
    """The bag of the chosen episodes at `path` (its .mcap file named after `name`)."""
    from ..bags.episodes import (BASE_TIME_NS, STEP_NS, T_ACT, T_OBS, T_PREF, T_RET, TOPIC, preference_message,
                                 stamped_header)
    from ..bags.writer import BagWriter
    from ..tasks.frames import frame_id

    report = ImportReport(task=task)
    ours = {r["episode_index"]: r for r in side["episodes"]} if side else {}
    ids = {}  # LeRobot episode index -> (source, episode id in the bag, length L)
    t = BASE_TIME_NS

    def topic(source, type_name):
        return f"{source}{TOPIC[type_name]}"

    with BagWriter(path, file_name=f"{name}_0.mcap") as bag:
        for e in wanted:
            parts = per_episode.get(e) or []
            if not parts:
                raise LeRobotError(f"episode {e}: no frames in the data files")
            j = np.concatenate([p["j"] for p in parts])
            order = np.argsort(j, kind="stable")
            n = int(rows[e]["length"])
            if len(j) != n or not np.array_equal(j[order], np.arange(n)):
                raise LeRobotError(f"episode {e}: {len(j)} frames with frame indices not 0..{n - 1} (meta says {n})")
            s = np.concatenate([p["s"] for p in parts])[order]
            a = np.concatenate([p["a"] for p in parts])[order] if parts[0]["a"] is not None else None
            mine = ours.get(e)
            if mine is not None:
                source, episode, length = mine["source"], int(mine["episode"]), n
                final = np.asarray(mine["final_state"], np.float32).reshape(-1)
                terminated = bool(mine["terminated"])
            else:
                if n < 2:
                    raise LeRobotError(f"episode {e} has {n} frame: an episode needs an action and a final state")
                source, episode, length, final, terminated = "", e, n - 1, s[n - 1], False
            ids[e] = (source, episode, length)
            images = frames.get(e, {})
            if with_camera and parts[0]["img"] is not None:
                listed = [im for p in parts for im in p["img"]]
                images = {int(j[order][k]): listed[order[k]] for k in range(n)}
            for step in range(length + 1):
                last = step == length
                state = final if last else s[step]
                bag.write_dict(topic(source, T_OBS), T_OBS, {
                    "header": stamped_header(t, task), "task": task, "episode": episode, "step": step,
                    "state": [float(x) for x in state], "terminated": last and terminated,
                    "truncated": last and not terminated}, t)
                if step in images:
                    bag.write_dict(f"{source}/nmrm/frame", "sensor_msgs/msg/CompressedImage", {
                        "header": stamped_header(t, frame_id(episode, step)), "format": "jpeg", "data": images[step]}, t)
                    report.frames += 1
                if not last and a is not None:
                    bag.write_dict(topic(source, T_ACT), T_ACT, {
                        "header": stamped_header(t), "episode": episode, "step": step,
                        "action": [float(x) for x in a[step]]}, t + 1)
                t += STEP_NS
            report.steps += length
            g = np.concatenate([p["g"] for p in parts])[order] if label_key else None
            if g is not None and not np.all(np.isfinite(g)):
                report.unlabelled += 1  # a missing or NaN reward: no return label
            elif g is not None:
                bag.write_dict(topic(source, T_RET), T_RET, {
                    "header": stamped_header(t), "task": task, "episode": episode, "length": length,
                    "return_value": float(g.sum()), "labeller": f"lerobot/{label_key}"}, t)
                report.labels += 1
            t += STEP_NS
        for label in (side or {}).get("labels", []):
            if label["episode_index"] in ids:
                source, episode, length = ids[label["episode_index"]]
                stamp = int(label["stamp_ns"])
                bag.write_dict(topic(source, T_RET), T_RET, {
                    "header": stamped_header(stamp), "task": task, "episode": episode, "length": length,
                    "return_value": float(label["return"]), "labeller": label["labeller"]}, t)
                report.labels += 1
                t += 1
        for pair in (side or {}).get("comparisons", []):
            a_, b_ = pair["episode_index_a"], pair["episode_index_b"]
            if a_ in ids and b_ in ids:
                (sa, ea, la), (sb, eb, lb) = ids[a_], ids[b_]
                msg = preference_message(task, ea, la, eb, lb, float(pair["p"]), pair["labeller"],
                                         int(pair["stamp_ns"]), sa, sb)
                bag.write_dict(topic("", T_PREF), T_PREF, msg, t)
                report.comparisons += 1
                t += 1
    report.episodes = len(wanted)
    return report
