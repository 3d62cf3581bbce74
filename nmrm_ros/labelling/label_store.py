"""The labels bag of a labelling node: every label written and flushed to disk at once, and the
labels of earlier sessions read back at start (no ROS).

`directory` holds one labels-only bag per session (`<directory>/<labeller>_<UTC time>/`, the
labeller id's '/' as '_'), each label a TrajectoryReturn on `topic`, each comparison a
TrajectoryPreference on `preference_topic`. A session killed hard (no
metadata.yaml) is repaired from its flushed chunks when the next session starts, so a crash loses
no label; `nmrm train --bag RECORDING --bag DIRECTORY/<session>` joins them to the recording.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from ..bags import BagError, BagWriter, iter_decoded, repair_bag

T_RET = "nmrm_msgs/msg/TrajectoryReturn"
T_PREF = "nmrm_msgs/msg/TrajectoryPreference"
WAITING_DIR = ".waiting_episodes"  # the labelling node's unlabelled episodes (waiting_episodes.py): hidden from shell globs, not a session


@dataclass
class StoredLabel:
    task: str
    episode: int
    length: int
    value: float
    labeller: str
    stamp_ns: int


@dataclass
class StoredComparison:
    task: str
    a: int
    b: int
    p: float
    labeller: str
    stamp_ns: int


class LabelStore:
    def __init__(self, directory: str | Path, labeller: str, topic: str = "/nmrm/trajectory_return",
                 preference_topic: str = "/nmrm/trajectory_preference") -> None:
        self.directory = Path(directory)
        self.labeller = labeller
        self.topic = topic
        self.preference_topic = preference_topic
        self.earlier_comparisons: list = []
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
        self.bag.add_topic(preference_topic, T_PREF)
        self.written = 0
        self.compared = 0

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
                    elif type_name == T_PREF:
                        self.earlier_comparisons.append(StoredComparison(
                            msg.task, int(msg.episode_a), int(msg.episode_b), (int(msg.preference) + 1) / 2,
                            msg.labeller, int(log_ns)))
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

    def compared_pairs(self, task: str) -> set:
        """(min, max) episode pairs of `task` this labeller compared in earlier sessions."""
        return {(min(c.a, c.b), max(c.a, c.b)) for c in self.earlier_comparisons
                if c.task == task and c.labeller == self.labeller}

    def append_comparison(self, task: str, a: int, length_a: int, b: int, length_b: int, p: float,
                          stamp_ns: int | None = None) -> dict:
        """Write one comparison (p = P(a better)) and flush it; returns the message as a dict."""
        from ..bags.episodes import preference_message

        t = time.time_ns() if stamp_ns is None else int(stamp_ns)
        message = preference_message(task, a, length_a, b, length_b, p, self.labeller, t)
        self.bag.write_dict(self.preference_topic, T_PREF, message, t)
        self.bag.flush()
        self.compared += 1
        return message

    def close(self) -> None:
        """Close this session's bag; a session without a label leaves no bag."""
        if self.written == 0 and self.compared == 0:
            self.bag.discard()
        else:
            self.bag.close()
