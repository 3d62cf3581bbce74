"""Finished, unlabelled episodes kept on disk, so that a restarted labelling node offers them again
(no ROS).

One file per episode, `<directory>/<task>_<episode>.npz` (states (L + 1, state_size) float32 and
the wall time it finished), written to a temporary name and renamed, so a kill leaves either the
whole file or none. A file is removed once its episode is labelled. At start, the newest
`max_episodes` of the task are read back (older ones are removed); a file that cannot be read is
reported and left in place.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class WaitingEpisode:
    episode: int
    states: np.ndarray     # (L + 1, state_size) float32
    finished_at: float     # wall time, s since the epoch


class WaitingEpisodes:
    def __init__(self, directory: str | Path, task: str) -> None:
        self.directory = Path(directory)
        self.task = task
        self.directory.mkdir(parents=True, exist_ok=True)

    def path(self, episode: int) -> Path:
        return self.directory / f"{self.task}_{int(episode)}.npz"

    def save(self, episode: int, states: np.ndarray, finished_at: float | None = None) -> None:
        """Keep a finished episode until it is labelled (atomic: write, fsync, rename)."""
        final = self.path(episode)
        tmp = final.with_name(final.name + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(f, states=np.asarray(states, np.float32),
                     finished_at=np.float64(time.time() if finished_at is None else finished_at))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, final)

    def remove(self, episode: int) -> None:
        self.path(episode).unlink(missing_ok=True)

    def load(self, skip: set, max_episodes: int) -> tuple[list, list]:
        """(the newest `max_episodes` kept episodes of the task not in `skip`, oldest first;
        one line per file that could not be read). Episodes in `skip` and older ones are removed."""
        found, errors = [], []
        for path in self.directory.glob(f"{self.task}_*.npz"):
            stem = path.stem[len(self.task) + 1:]
            if not stem.isdigit():
                continue
            episode = int(stem)
            if episode in skip:
                path.unlink(missing_ok=True)
                continue
            try:
                with np.load(path) as data:
                    states, finished_at = data["states"], float(data["finished_at"])
                if states.ndim != 2 or len(states) < 2:
                    raise ValueError(f"states of shape {states.shape}")
            except Exception as exc:  # noqa: BLE001 - any unreadable file is reported, not fatal
                errors.append(f"{path}: {exc}")
                continue
            found.append(WaitingEpisode(episode, states, finished_at))
        found.sort(key=lambda e: e.finished_at)
        for old in found[:-max_episodes] if len(found) > max_episodes else []:
            self.remove(old.episode)
        return found[-max_episodes:], errors
