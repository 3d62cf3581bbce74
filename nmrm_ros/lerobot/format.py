"""The LeRobot dataset format v3.0 on disk, as LeRobot 0.4.x writes and reads it (no LeRobot import).

    <root>/meta/info.json                       codebase_version "v3.0", fps, features, totals, path templates
    <root>/meta/stats.json                      {feature: {min, max, mean, std, count, q01, q10, q50, q90, q99}}
    <root>/meta/tasks.parquet                   one row per task text (pandas index "task", column task_index)
    <root>/meta/episodes/chunk-000/file-000.parquet   one row per episode: length, files, index range, stats/...
    <root>/data/chunk-000/file-000.parquet      one row per frame: the features + timestamp, frame_index,
                                                episode_index, index, task_index
    <root>/videos/<camera key>/chunk-000/file-000.mp4  the frames of consecutive episodes

Chunks hold at most `CHUNKS_SIZE` files; a data file is closed past `DATA_FILE_MB`, a video file past
`VIDEO_FILE_MB`; an episode is never split between files. A feature of shape (1,) is a scalar
column, one of shape (N,) a fixed-size list. Statistics are LeRobot's (`compute_stats`): per
episode, then aggregated (min of mins, count-weighted mean, pooled std, count-weighted mean of
the quantiles); an image's are per channel in [0, 1], shaped (3, 1, 1). The quantiles here are
exact (numpy), where LeRobot reads them off a 5000-bin histogram: they agree to its bin width.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILE_MB = 100
VIDEO_FILE_MB = 200
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
#: what LeRobot has no place for (final observations, labels, comparisons, where it came from)
NMRM_DIR = "meta/nmrm"
#: the features every LeRobot dataset has, after its own
DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
STAT_NAMES = ("min", "max", "mean", "std", "count") + tuple(f"q{int(q * 100):02d}" for q in QUANTILES)


class LeRobotError(ValueError):
    """A dataset that cannot be read or written, in one line (the CLI prints it)."""


def next_file(chunk: int, file: int) -> tuple[int, int]:
    """The (chunk, file) indices after (chunk, file): a chunk holds CHUNKS_SIZE files."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


# ------------------------------------------------------------------------- statistics
def feature_stats(values: np.ndarray) -> dict:
    """LeRobot's statistics of one episode's values (N, D) (or (N,)): each (D,) float64, count (1,)."""
    v = np.asarray(values, dtype=np.float64)
    v = v.reshape(len(v), -1)
    out = {"min": v.min(0), "max": v.max(0), "mean": v.mean(0), "std": v.std(0),
           "count": np.array([len(v)], dtype=np.int64)}
    qs = np.quantile(v, QUANTILES, axis=0) if len(v) > 1 else np.repeat(v.mean(0)[None], len(QUANTILES), 0)
    for q, row in zip(QUANTILES, qs):
        out[f"q{int(q * 100):02d}"] = row
    return out


def image_stats(frames: np.ndarray, max_frames: int = 100) -> dict:
    """Statistics of an episode's RGB frames (N, H, W, 3) uint8 as LeRobot keeps an image's: per
    channel over the pixels of at most `max_frames` evenly spaced frames, in [0, 1], each (3, 1, 1);
    count = the frames sampled."""
    frames = np.asarray(frames)
    pick = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    channels = np.ascontiguousarray(frames[pick].reshape(-1, 3).T, dtype=np.float64) / 255.0  # (3, pixels)
    out = {"min": channels.min(1), "max": channels.max(1), "mean": channels.mean(1), "std": channels.std(1)}
    for q, row in zip(QUANTILES, np.quantile(channels, QUANTILES, axis=1)):
        out[f"q{int(q * 100):02d}"] = row
    out = {k: v.reshape(3, 1, 1) for k, v in out.items()}
    out["count"] = np.array([len(pick)], dtype=np.int64)
    return out


def aggregate_stats(episodes: list) -> dict:
    """The dataset's statistics from its episodes' (same keys): min of mins, max of maxes,
    count-weighted mean, pooled std, summed count, count-weighted mean of each quantile."""
    counts = np.array([float(e["count"][0]) for e in episodes])
    w = counts / counts.sum()
    shape = np.asarray(episodes[0]["mean"]).shape
    weight = w.reshape(-1, *([1] * len(shape)))
    means = np.stack([e["mean"] for e in episodes])
    mean = (weight * means).sum(0)
    var = (weight * (np.stack([e["std"] for e in episodes]) ** 2 + (means - mean) ** 2)).sum(0)
    out = {"min": np.min(np.stack([e["min"] for e in episodes]), 0),
           "max": np.max(np.stack([e["max"] for e in episodes]), 0),
           "mean": mean, "std": np.sqrt(var), "count": np.array([int(counts.sum())], dtype=np.int64)}
    for name in STAT_NAMES[5:]:
        out[name] = (weight * np.stack([e[name] for e in episodes])).sum(0)
    return out


def stats_json(stats: dict) -> dict:
    """{feature: {stat: array}} as JSON lists."""
    return {k: {s: np.asarray(v).tolist() for s, v in st.items()} for k, st in stats.items()}


# ------------------------------------------------------------------------- columns
def arrow_column(values: np.ndarray, dtype: str):
    """A parquet column of per-frame values (N, D) (or (N,)): a scalar column where D is 1,
    else a fixed-size list of D, as LeRobot's `datasets` features make them."""
    import pyarrow as pa

    v = np.asarray(values, dtype=dtype)
    if v.ndim == 1 or v.shape[1] == 1:
        return pa.array(v.reshape(-1))
    return pa.FixedSizeListArray.from_arrays(pa.array(v.reshape(-1)), v.shape[1])


def column_values(table, name: str, width: int) -> np.ndarray:
    """Per-frame values (N, width) of column `name` of a data table (scalar or list column)."""
    import pyarrow as pa

    col = table.column(name).combine_chunks()
    if pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type) or pa.types.is_large_list(col.type):
        flat = col.flatten().to_numpy(zero_copy_only=False)
        if len(flat) != len(col) * width:
            raise LeRobotError(f"column {name!r} holds {len(flat)} values for {len(col)} frames, not {width} each")
        return flat.reshape(len(col), width)
    return col.to_numpy(zero_copy_only=False).reshape(len(col), 1)


# ------------------------------------------------------------------------- meta files
def write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=4, ensure_ascii=False))


def read_info(root: Path) -> dict:
    """meta/info.json of a LeRobot v3.0 dataset at `root`; LeRobotError (one line) for anything else."""
    path = Path(root) / INFO_PATH
    if not Path(root).is_dir():
        raise LeRobotError(f"{root}: not a directory (a LeRobot dataset is a directory with meta/info.json)")
    if not path.is_file():
        raise LeRobotError(f"{root}: no {INFO_PATH}: not a LeRobot dataset")
    try:
        info = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LeRobotError(f"{path}: not JSON ({exc})") from None
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        raise LeRobotError(f"{path}: no features table")
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        hint = (" (convert it with LeRobot's lerobot.datasets.v30.convert_dataset_v21_to_v30)"
                if str(version).startswith("v2") else "")
        raise LeRobotError(f"{root}: LeRobot dataset format {version!r}; this reads {CODEBASE_VERSION!r}{hint}")
    for key in ("fps", "total_episodes", "total_frames", "data_path"):
        if key not in info:
            raise LeRobotError(f"{path}: no {key!r}")
    return info


def write_tasks(root: Path, tasks: list) -> None:
    """meta/tasks.parquet: row i is task i, a pandas frame indexed by the task text (column
    task_index), as LeRobot's `write_tasks` makes it; the pandas metadata is written by hand (no
    pandas here) so that LeRobot's `pd.read_parquet` gets the index back."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                            "metadata": {"encoding": "UTF-8"}}],
        "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                     "numpy_type": "int64", "metadata": None},
                    {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object",
                     "metadata": None}],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = pa.table({"task_index": pa.array(np.arange(len(tasks), dtype=np.int64)),
                      "task": pa.array([str(t) for t in tasks], pa.string())})
    table = table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})
    path = Path(root) / TASKS_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def read_tasks(root: Path) -> list:
    """The task texts of meta/tasks.parquet, by task_index (LeRobot 0.4's unnamed index column
    `__index_level_0__` or 0.5's `task`)."""
    path = Path(root) / TASKS_PATH
    if not path.is_file():
        return []
    table = read_parquet(path)
    names = [n for n in ("task", "__index_level_0__") if n in table.column_names]
    if not names or "task_index" not in table.column_names:
        raise LeRobotError(f"{path}: no task column (task or the pandas index) beside task_index")
    texts = table.column(names[0]).to_pylist()
    order = table.column("task_index").to_pylist()
    out = [""] * (max(order) + 1 if order else 0)
    for i, t in zip(order, texts):
        out[int(i)] = str(t)
    return out


def vector_width(spec: dict, key: str) -> int:
    """The width of a vector feature of info.json (`spec`); LeRobotError for images, strings, arrays."""
    shape = spec.get("shape") or [1]
    if spec.get("dtype") in ("video", "image", "string") or len(shape) != 1:
        raise LeRobotError(f"feature {key!r} is {spec.get('dtype')} of shape {shape}, not a vector")
    return int(shape[0])


def read_episode_rows(root: Path) -> list:
    """meta/episodes' rows (episode_index, length, files...) sorted by episode; LeRobotError if absent."""
    files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not files:
        raise LeRobotError(f"{root}: no meta/episodes/*/*.parquet")
    rows = []
    for f in files:
        rows.extend(read_parquet(f).to_pylist())
    missing = [c for c in ("episode_index", "length") if rows and c not in rows[0]]
    if missing:
        raise LeRobotError(f"{files[0]}: no {missing[0]!r} column")
    rows.sort(key=lambda r: int(r["episode_index"]))
    return rows


def read_parquet(path: Path):
    """A parquet file as a pyarrow Table; LeRobotError (one line) for a missing or corrupt one."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.read_table(path)
    except FileNotFoundError:
        raise LeRobotError(f"{path}: missing") from None
    except (pa.ArrowException, OSError) as exc:
        raise LeRobotError(f"{path}: not a readable parquet file ({str(exc).splitlines()[0]})") from None


def temporary_sibling(out: Path) -> Path:
    """A fresh directory beside `out` to write into and rename to `out` once complete, so that
    a failed export or import leaves nothing half-written."""
    out = Path(out)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.partial")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    return tmp
