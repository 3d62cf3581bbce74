"""The episodes waiting for a person's label, and the labels given (no ROS).

An episode is keyed by (task, episode) as in the labeller contract. `LabelQueue` holds finished
episodes (states (L+1, state_size), the final one included) and the labels of this labeller;
`pending()` is the queue (unlabelled, not skipped): oldest first, or, with a scorer (see
`active.py`), the most informative first, each episode carrying why; `label()` validates a return
against the task's range and records it (a second label of the same episode is a correction: the
latest one counts, for training too).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..tasks import task_info

#: returns a label may take, per task: T = 100 steps of rewards in [0, 1] (Timer: -1 for each of
#: the first 50, +1 after);
#: Lunar Lander's per-step rewards are bounded by its oracle's terms, returns stay within ±1000
RETURN_RANGES = {"timer": (-50.0, 50.0), "moving": (0.0, 100.0), "key": (0.0, 100.0),
                 "charger": (0.0, 100.0), "lunar_lander": (-1000.0, 1000.0)}


class LabelError(ValueError):
    """A label that cannot be accepted (unknown episode, not a finite number, out of range)."""


def return_range(task: str) -> tuple:
    """(low, high) of the returns a label of `task` may take; (None, None) for a task of the
    user's (a task spec), whose range we do not know: any finite number."""
    task_info(task)  # validates the name
    return RETURN_RANGES.get(task, (None, None))


@dataclass
class Episode:
    task: str
    episode: int
    states: np.ndarray          # (L + 1, state_size): steps 0..L, the last one final
    finished_at: float          # wall time (s since the epoch) of the final observation
    skipped: bool = False
    spread: float | None = None     # the scorer's: std of the members' predicted returns
    predicted: float | None = None  # the scorer's: mean predicted return

    @property
    def why(self) -> str:
        if self.spread is None:
            return "oldest first"
        return f"models disagree: return {self.predicted:.1f} ± {self.spread:.2f}"

    @property
    def length(self) -> int:
        return len(self.states) - 1


@dataclass
class Label:
    episode: int
    value: float
    at: float                   # wall time, s since the epoch
    corrections: int = 0        # labels of this episode before this one


@dataclass
class LabelQueue:
    task: str
    max_episodes: int = 1000    # oldest finished episodes are dropped beyond this
    episodes: dict = field(default_factory=dict)    # episode id -> Episode
    labels: dict = field(default_factory=dict)      # episode id -> latest Label
    done_before: set = field(default_factory=set)   # labelled in an earlier session (not asked again)
    scorer: object = None       # .score(states (L, d)) -> (spread, mean) and .ordering; None: oldest first

    def __post_init__(self) -> None:
        self.low, self.high = return_range(self.task)
        self.lock = threading.Lock()

    @property
    def ordering(self) -> str:
        return "oldest first" if self.scorer is None else self.scorer.ordering

    def _score(self, ep: Episode) -> None:
        if self.scorer is None or self.scorer.ordering == "oldest first":
            ep.spread = ep.predicted = None
        else:
            ep.spread, ep.predicted = self.scorer.score(ep.states[:-1])

    def set_scorer(self, scorer) -> None:
        """Order the queue with `scorer` from now on (None: oldest first); rescores every episode."""
        with self.lock:
            self.scorer = scorer
            for ep in self.episodes.values():
                self._score(ep)

    def add(self, episode: int, states: np.ndarray, finished_at: float | None = None) -> bool:
        """A finished episode; False (and not queued) if it was labelled already."""
        with self.lock:
            if episode in self.labels or episode in self.done_before:
                return False
            ep = Episode(self.task, int(episode), np.asarray(states, np.float32),
                         time.time() if finished_at is None else finished_at)
            self._score(ep)
            self.episodes[episode] = ep
            while len(self.episodes) > self.max_episodes:
                del self.episodes[min(self.episodes, key=lambda e: self.episodes[e].finished_at)]
            return True

    def pending(self) -> list:
        """Unlabelled, unskipped episodes: the largest spread first with a scorer, else (and on
        ties) oldest first."""
        with self.lock:
            waiting = [e for e in self.episodes.values()
                       if e.episode not in self.labels and not e.skipped]
        return sorted(waiting, key=lambda e: (-(e.spread or 0.0), e.finished_at))

    def get(self, episode: int) -> Episode:
        with self.lock:
            if episode not in self.episodes:
                raise LabelError(f"no episode {episode} here")
            return self.episodes[episode]

    def validate(self, value) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise LabelError(f"a return must be a finite number, got {value!r}")
        if self.low is not None and not self.low <= value <= self.high:
            raise LabelError(f"return {value} is outside [{self.low:g}, {self.high:g}] for {self.task}")
        return float(value)

    def label(self, episode: int, value) -> tuple:
        """Record a label (or a correction); returns (Label, Episode)."""
        value = self.validate(value)
        ep = self.get(episode)
        with self.lock:
            before = self.labels.get(episode)
            record = Label(episode, value, time.time(), 0 if before is None else before.corrections + 1)
            self.labels[episode] = record
            ep.skipped = False
        return record, ep

    def skip(self, episode: int) -> None:
        self.get(episode).skipped = True

    def history(self) -> list:
        """The labels given in this session, newest first."""
        with self.lock:
            return sorted(self.labels.values(), key=lambda r: r.at, reverse=True)
