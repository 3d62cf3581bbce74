"""The rendered frames of episodes, kept for the labelling page (`nmrm/frame`, see
nmrm_ros.tasks.frames): episode -> step -> (format, encoded image), at most `max_bytes` in all,
the oldest episodes' frames dropped first. Thread-safe: the ROS thread adds, the web thread reads."""

from __future__ import annotations

import threading
from collections import OrderedDict


class FrameStore:
    def __init__(self, max_bytes: int = 200_000_000) -> None:
        self.max_bytes = int(max_bytes)
        self.bytes = 0
        self.dropped_episodes = 0
        self._episodes: OrderedDict = OrderedDict()  # episode -> {step: (format, data)}
        self._lock = threading.Lock()

    def add(self, episode: int, step: int, fmt: str, data: bytes) -> None:
        with self._lock:
            frames = self._episodes.setdefault(int(episode), {})
            old = frames.get(int(step))
            self.bytes += len(data) - (len(old[1]) if old else 0)
            frames[int(step)] = (fmt, bytes(data))
            while self.bytes > self.max_bytes and len(self._episodes) > 1:
                _, gone = self._episodes.popitem(last=False)
                self.bytes -= sum(len(d) for _, d in gone.values())
                self.dropped_episodes += 1

    def any(self) -> bool:
        """Whether any episode has a frame (the graph renders: every episode's frames will come)."""
        with self._lock:
            return bool(self._episodes)

    def steps(self, episode: int) -> list:
        """The steps of `episode` that have a frame, in order."""
        with self._lock:
            return sorted(self._episodes.get(int(episode), {}))

    def get(self, episode: int, step: int) -> tuple | None:
        """(format, data) of the frame of (episode, step), or None."""
        with self._lock:
            return self._episodes.get(int(episode), {}).get(int(step))
