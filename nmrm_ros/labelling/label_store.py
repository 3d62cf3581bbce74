"""The labels bag of a labelling node: every label written and flushed to disk at once, and the
labels of earlier sessions read back at start (no ROS).

`directory` holds one labels-only bag per session (`<directory>/<labeller>_<UTC time>/`, the
labeller id's '/' as '_'), each label a TrajectoryReturn on `topic`. A session killed hard (no
metadata.yaml) is repaired from its flushed chunks when the next session starts, so a crash loses
no label; `nmrm train --bag RECORDING --bag DIRECTORY/<session>` joins them to the recording.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from ..bags import BagError, BagWriter, iter_decoded, repair_bag

T_RET = "nmrm_msgs/msg/TrajectoryReturn"
WAITING_DIR = ".waiting_episodes"  # the labelling node's unlabelled episodes (waiting_episodes.py): hidden from shell globs, not a session


@dataclass
class StoredLabel:
    task: str
    episode: int
    length: int
    value: float
    labeller: str
    stamp_ns: int


class LabelStore:
    def __init__(self, directory: str | Path, labeller: str, topic: str = "/nmrm/trajectory_return") -> None:
        self.directory = Path(directory)
        self.labeller = labeller
        self.topic = topic
        self.directory.mkdir(parents=True, exist_ok=True)
        self.repaired: list = []   # sessions repaired at start
        self.unreadable: list = [] # sessions without a readable label (e.g. killed before the first)
        self.earlier = self._read_earlier()
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        name = f"{labeller.replace('/', '_')}_{stamp}"
        path, n = self.directory / name, 1
        while path.exists():
            path, n = self.directory / f"{name}_{n}", n + 1
        self.path = path
        self.bag = BagWriter(path, chunk_size=4096)
        self.bag.add_topic(topic, T_RET)
        self.written = 0

    def _read_earlier(self) -> list:
        labels: list = []
        for session in sorted(p for p in self.directory.iterdir() if p.is_dir()):
            if session.name.endswith(".repairing") or session.name == WAITING_DIR:
                continue
            if not (session / "metadata.yaml").is_file():
                try:
                    repair_bag(session)
                    self.repaired.append(session)
                except BagError:
                    self.unreadable.append(session)
                    continue
            try:
                for _, type_name, log_ns, msg in iter_decoded(session):
                    if type_name == T_RET:
                        labels.append(StoredLabel(msg.task, int(msg.episode), int(msg.length),
                                                  float(msg.return_value), msg.labeller, int(log_ns)))
            except BagError:
                self.unreadable.append(session)
        return sorted(labels, key=lambda s: s.stamp_ns)

    def labelled_episodes(self, task: str) -> set:
        """Episodes of `task` this labeller labelled in earlier sessions."""
        return {s.episode for s in self.earlier if s.task == task and s.labeller == self.labeller}

    def append(self, task: str, episode: int, length: int, value: float, stamp_ns: int | None = None) -> None:
        """Write one label and flush it to disk (it survives a kill -9 from now on)."""
        t = time.time_ns() if stamp_ns is None else int(stamp_ns)
        self.bag.write_dict(self.topic, T_RET, {
            "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": ""},
            "task": task, "episode": int(episode), "length": int(length), "return_value": float(value),
            "labeller": self.labeller}, t)
        self.bag.flush()
        self.written += 1

    def close(self) -> None:
        self.bag.close()
