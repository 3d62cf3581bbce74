"""Labels as plain records, to and from bags and files (no ROS).

A label record is a dict (`nmrm_ros.bags.label_records.label_record`): task, source (the namespace of
its topics, '' for /nmrm/...), episode, length, return, labeller, stamp_ns (when it was given).
Files: JSON lines (`.jsonl`, one record per line) or CSV (`.csv`, a header row with those field
names), written and read by `write_labels` / `read_labels`; `write_labels_bag` turns records into
a labels-only bag that `nmrm train --bag RECORDING --bag LABELS` joins to its recording as any
labeller's bag.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

FIELDS = ("task", "source", "episode", "length", "return", "labeller", "stamp_ns")
T_RET = "nmrm_msgs/msg/TrajectoryReturn"
SUFFIXES = (".jsonl", ".csv")


def read_bag_labels(paths: list) -> list[dict]:
    """Every TrajectoryReturn in the bags at `paths`, as records, in the order they were written."""
    from ..bags import iter_decoded
    from ..bags.label_records import label_record
    from ..bags.schemas import split_topic

    records = []
    for path in paths:
        for topic, type_name, log_ns, m in iter_decoded(path):
            if type_name != T_RET:
                continue
            stamp = int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec) or int(log_ns)
            records.append(label_record(m.task, split_topic(topic)[0], m.episode, m.length,
                                        m.return_value, m.labeller, stamp))
    return records


T_PREF = "nmrm_msgs/msg/TrajectoryPreference"


def read_bag_comparisons(paths: list) -> list[dict]:
    """Every TrajectoryPreference in the bags at `paths`, as comparison records, in order."""
    from ..bags import iter_decoded
    from ..bags.label_records import comparison_record
    from ..bags.schemas import split_topic

    records = []
    for path in paths:
        for topic, type_name, log_ns, m in iter_decoded(path):
            if type_name != T_PREF or int(m.preference) not in (-1, 0, 1):
                continue
            stamp = int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec) or int(log_ns)
            records.append(comparison_record(m.task, m.source_a or split_topic(topic)[0], m.episode_a, m.length_a,
                                             m.episode_b, m.length_b, (int(m.preference) + 1) / 2, m.labeller, stamp))
    return records


def latest_comparisons(records: list[dict]) -> list[dict]:
    """The latest answer per (labeller, source, task, unordered pair), oriented as given."""
    out: dict = {}
    for r in sorted(records, key=lambda r: r["stamp_ns"]):
        out[(r["labeller"], r["source"], r["task"], min(r["a"], r["b"]), max(r["a"], r["b"]))] = r
    return list(out.values())


def latest(records: list[dict]) -> list[dict]:
    """The latest label per (labeller, source, task, episode): a correction replaces what it corrects."""
    out: dict = {}
    for r in sorted(records, key=lambda r: r["stamp_ns"]):
        out[(r["labeller"], r["source"], r["task"], r["episode"])] = r
    return list(out.values())


def _check(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{path}: a labels file is .jsonl or .csv, not {suffix or 'without a suffix'!r}")
    return suffix


def write_labels(records: list[dict], path: str | Path) -> Path:
    """Write records as JSON lines or CSV (by the suffix of `path`)."""
    path = Path(path)
    suffix = _check(path)
    with open(path, "w", newline="") as f:
        if suffix == ".jsonl":
            for r in records:
                f.write(json.dumps({k: r[k] for k in FIELDS}) + "\n")
        else:
            w = csv.DictWriter(f, FIELDS)
            w.writeheader()
            w.writerows({k: r[k] for k in FIELDS} for r in records)
    return path


def _record(raw: dict, where: str) -> dict:
    """A checked record from a row of strings or JSON values; ValueError naming `where`."""
    missing = [k for k in FIELDS if k not in raw]
    if missing:
        raise ValueError(f"{where}: missing field(s) {', '.join(missing)} (fields: {', '.join(FIELDS)})")
    try:
        r = {"task": str(raw["task"]), "source": str(raw["source"] or ""), "episode": int(raw["episode"]),
             "length": int(raw["length"]), "return": float(raw["return"]), "labeller": str(raw["labeller"]),
             "stamp_ns": int(raw["stamp_ns"])}
    except (TypeError, ValueError):
        raise ValueError(f"{where}: episode, length and stamp_ns must be integers and return a number") from None
    if not r["task"] or not r["labeller"]:
        raise ValueError(f"{where}: task and labeller must not be empty")
    if r["episode"] < 0 or r["length"] < 1 or not math.isfinite(r["return"]):
        raise ValueError(f"{where}: episode >= 0, length >= 1 and a finite return are needed")
    return r


def read_labels(path: str | Path) -> list[dict]:
    """Records of a .jsonl or .csv labels file; ValueError (one line, naming the line) if one is bad."""
    path = Path(path)
    suffix = _check(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    records = []
    try:
        with open(path, newline="") as f:
            if suffix == ".jsonl":
                for n, line in enumerate(f, 1):
                    if not line.strip():
                        continue
                    try:
                        raw = json.loads(line)
                    except ValueError:
                        raise ValueError(f"{path}:{n}: not a JSON object") from None
                    if not isinstance(raw, dict):
                        raise ValueError(f"{path}:{n}: not a JSON object")
                    records.append(_record(raw, f"{path}:{n}"))
            else:
                for n, raw in enumerate(csv.DictReader(f), 2):
                    records.append(_record(raw, f"{path}:{n}"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    return records


def write_labels_bag(records: list[dict], out: str | Path) -> Path:
    """A labels-only bag of `records` (each on `<source>/nmrm/trajectory_return`, log time = its stamp)."""
    from ..bags import BagWriter

    with BagWriter(out) as bag:
        for r in sorted(records, key=lambda r: r["stamp_ns"]):
            topic = f"{r['source']}/nmrm/trajectory_return"
            bag.add_topic(topic, T_RET)
            t = int(r["stamp_ns"])
            bag.write_dict(topic, T_RET, {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": ""},
                "task": r["task"], "episode": r["episode"], "length": r["length"],
                "return_value": r["return"], "labeller": r["labeller"]}, t)
    return Path(out)


def checkpoint_labels(path: str | Path) -> list[dict]:
    """The labels a checkpoint was built from (its metadata's record of its data); ValueError if it
    holds none (a checkpoint from generated data, or one written before labels were recorded)."""
    from ..mil.checkpoint import load_checkpoint

    _, meta = load_checkpoint(path)
    labels = meta.data.meta.get("labels")
    if not isinstance(labels, list):
        source = str(meta.data.source) or "unknown data"
        raise ValueError(f"{path}: records no labels (trained on {source}); checkpoints trained from "
                         f"bags or by the trainer node record theirs")
    return labels


def checkpoint_comparisons(path: str | Path) -> list[dict]:
    """The comparisons a checkpoint was built from ([] if none are recorded)."""
    from ..mil.checkpoint import load_checkpoint

    _, meta = load_checkpoint(path)
    found = meta.data.meta.get("comparisons")
    return found if isinstance(found, list) else []
