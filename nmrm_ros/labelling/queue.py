"""The episodes waiting for people's labels, and the labels given (no ROS).

An episode is keyed by (task, episode) as in the labeller contract. `LabelQueue` holds finished
episodes (states (L+1, state_size), the final one included) and the labels of every person of a
team (`people`; one person is a team of one, named ""). `pending(person)` is that person's queue:
oldest first, or, with a scorer (see `active.py`), the most informative first, each episode
carrying why. `assignment` says who is asked what: "split" (each episode to one person: once
anyone labelled it, or while someone else has it open, it is not offered to the others) or
"overlap" (every episode to every person, for agreement). `label()` validates a return against the
task's range and records it (a person's second label of an episode is a correction: the latest one
counts, for training too). Gold episodes (`gold`: episodes whose return is known, to check the
people) are asked of everyone whatever the assignment.

Comparisons (feedback preferences): `pending_pairs(person)` offers pairs of the queued episodes
to compare, among the `pair_window` oldest episodes that still need comparisons (an episode needs
`comparisons_per_episode` answered ones: by anyone with split assignment, by this person with
overlap); with an ensemble scorer the pairs its members disagree on most come first
(`active.pair_disagreement`), else the oldest pairs. `compare()` records an answer (a, b, p) — a
person's second answer on a pair is a correction — and `cant_tell()` records that a person will
not be asked that pair again ("can't tell" is no comparison).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..tasks import task_info

class LabelError(ValueError):
    """A label that cannot be accepted (unknown episode, not a finite number, out of range)."""


def return_range(task: str) -> tuple:
    """(low, high) of the returns a label of `task` may take; (None, None) for a task of the
    user's (a task spec), whose range we do not know: any finite number."""
    return task_info(task).return_range


@dataclass
class Episode:
    task: str
    episode: int
    states: np.ndarray          # (L + 1, state_size): steps 0..L, the last one final
    finished_at: float          # wall time (s since the epoch) of the final observation
    spread: float | None = None     # the scorer's: std of the members' predicted returns
    predicted: float | None = None  # the scorer's: mean predicted return
    members: np.ndarray | None = None  # the scorer's: each member's predicted return (K,)

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
    corrections: int = 0        # labels of this episode by this person before this one
    person: str = ""            # who gave it


@dataclass
class Comparison:
    a: int                      # the episode shown on the left
    b: int                      # ... on the right
    p: float                    # P(a better) as answered: 1 a, 0 b, 0.5 equal
    at: float                   # wall time, s since the epoch
    corrections: int = 0        # answers on this pair by this person before this one
    person: str = ""


PREFERENCES = {"a": 1.0, "b": 0.0, "equal": 0.5}
ASSIGNMENTS = ("split", "overlap")


@dataclass
class LabelQueue:
    task: str
    max_episodes: int = 1000    # oldest finished episodes are dropped beyond this
    people: tuple = ("",)       # the team's names ("": one unnamed person)
    assignment: str = "split"   # split | overlap (see the module docstring)
    take_s: float = 300.0       # split: an episode opened by a person is theirs for this long
    episodes: dict = field(default_factory=dict)    # episode id -> Episode
    labels: dict = field(default_factory=dict)      # (person, episode id) -> latest Label
    done_before: dict = field(default_factory=dict) # person -> episodes labelled in earlier sessions
    scorer: object = None       # .score(states (L, d)) -> (spread, mean, members) and .ordering; None: oldest first
    comparisons_per_episode: int = 3  # answered comparisons an episode needs (see the module docstring)
    pair_window: int = 30       # pairs are offered among this many oldest episodes that need comparisons
    comparisons: dict = field(default_factory=dict)  # (person, min(a, b), max(a, b)) -> latest Comparison
    compared_before: set = field(default_factory=set)  # (person, min(a, b), max(a, b)) answered in earlier sessions

    def __post_init__(self) -> None:
        self.low, self.high = return_range(self.task)
        if self.assignment not in ASSIGNMENTS:
            raise ValueError(f"assignment must be one of {', '.join(ASSIGNMENTS)}, got {self.assignment!r}")
        self.people = tuple(self.people)
        self.lock = threading.Lock()
        self.skipped: set = set()   # (person, episode)
        self.gold: set = set()      # episodes asked of everyone (their returns are known)
        self.taken: dict = {}       # episode -> (person, until: wall time)
        self.cant: set = set()      # (person, min(a, b), max(a, b)): "can't tell" answers

    @property
    def ordering(self) -> str:
        return "oldest first" if self.scorer is None else self.scorer.ordering

    def _score(self, ep: Episode) -> None:
        if self.scorer is None or self.scorer.ordering == "oldest first":
            ep.spread = ep.predicted = ep.members = None
        else:
            ep.spread, ep.predicted, ep.members = self.scorer.score(ep.states[:-1])

    def set_scorer(self, scorer) -> None:
        """Order the queue with `scorer` from now on (None: oldest first); rescores every episode."""
        with self.lock:
            self.scorer = scorer
            for ep in self.episodes.values():
                self._score(ep)

    def _labelled_by(self, episode: int) -> set:
        """People who labelled `episode`, this session or before (call with the lock held)."""
        return ({p for p in self.people if (p, episode) in self.labels}
                | {p for p, done in self.done_before.items() if episode in done})

    def done(self, episode: int) -> bool:
        """Nobody is to be asked for `episode` any more: split, someone labelled it; overlap, everyone did."""
        with self.lock:
            by = self._labelled_by(episode)
        return bool(by) if self._split(episode) else set(self.people) <= by

    def _split(self, episode: int) -> bool:
        return self.assignment == "split" and episode not in self.gold

    def add(self, episode: int, states: np.ndarray, finished_at: float | None = None) -> bool:
        """A finished episode; False (and not queued) if nobody is to be asked for it any more."""
        if self.done(episode):
            return False
        with self.lock:
            ep = Episode(self.task, int(episode), np.asarray(states, np.float32),
                         time.time() if finished_at is None else finished_at)
            self._score(ep)
            self.episodes[episode] = ep
            while len(self.episodes) > self.max_episodes:
                del self.episodes[min(self.episodes, key=lambda e: self.episodes[e].finished_at)]
            return True

    def _check_person(self, person: str) -> None:
        if person not in self.people:
            raise LabelError(f"{person!r} is not one of this page's people")

    def pending(self, person: str = "") -> list:
        """`person`'s queue: episodes they have not labelled or skipped (split: nor anyone else
        labelled, nor someone else has open); the largest spread first with a scorer, else (and
        on ties) oldest first."""
        now = time.time()
        with self.lock:
            waiting = []
            for e in self.episodes.values():
                by = self._labelled_by(e.episode)
                if person in by or (person, e.episode) in self.skipped:
                    continue
                if self._split(e.episode):
                    holder, until = self.taken.get(e.episode, (person, 0.0))
                    if by or (holder != person and until > now):
                        continue
                waiting.append(e)
        return sorted(waiting, key=lambda e: (-(e.spread or 0.0), e.finished_at))

    def get(self, episode: int) -> Episode:
        with self.lock:
            if episode not in self.episodes:
                raise LabelError(f"no episode {episode} here")
            return self.episodes[episode]

    def take(self, episode: int, person: str = "") -> Episode:
        """`person` opens `episode`: with split assignment it is theirs (not offered to the others)
        for `take_s` seconds, unless someone else has it open already."""
        ep = self.get(episode)
        with self.lock:
            holder, until = self.taken.get(episode, (person, 0.0))
            if self._split(episode) and (holder == person or until <= time.time()):
                self.taken[episode] = (person, time.time() + self.take_s)
        return ep

    def validate(self, value) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise LabelError(f"a return must be a finite number, got {value!r}")
        if self.low is not None and not self.low <= value <= self.high:
            raise LabelError(f"return {value} is outside [{self.low:g}, {self.high:g}] for {self.task}")
        return float(value)

    def label(self, episode: int, value, person: str = "") -> tuple:
        """Record `person`'s label (or correction); returns (Label, Episode)."""
        self._check_person(person)
        value = self.validate(value)
        ep = self.get(episode)
        with self.lock:
            before = self.labels.get((person, episode))
            record = Label(episode, value, time.time(), 0 if before is None else before.corrections + 1, person)
            self.labels[(person, episode)] = record
            self.skipped.discard((person, episode))
            self.taken.pop(episode, None)
        return record, ep

    def label_of(self, episode: int, person: str = "") -> Label | None:
        with self.lock:
            return self.labels.get((person, episode))

    def skip(self, episode: int, person: str = "") -> None:
        self._check_person(person)
        self.get(episode)
        with self.lock:
            self.skipped.add((person, episode))
            if episode in self.taken and self.taken[episode][0] == person:
                del self.taken[episode]

    def history(self, person: str | None = None) -> list:
        """The labels given in this session (by `person`; None: by everyone), newest first."""
        with self.lock:
            return sorted((r for r in self.labels.values() if person is None or r.person == person),
                          key=lambda r: r.at, reverse=True)

    # -- comparisons ---------------------------------------------------------------------------
    def _answered(self) -> set:
        """(person, min, max) of every comparison answered, this session or before (lock held)."""
        return set(self.comparisons) | self.compared_before

    def _compared_counts(self, person: str, answered: set) -> dict:
        """episode -> answered comparisons of it that count for `person` (lock held)."""
        counts: dict = {}
        for who, a, b in answered:
            if self.assignment == "split" or who == person:
                counts[a] = counts.get(a, 0) + 1
                counts[b] = counts.get(b, 0) + 1
        return counts

    def pending_pairs(self, person: str = "", limit: int = 20) -> list:
        """`person`'s pairs to compare: (a, b, disagreement or None), best first (see the module
        docstring); a is the older episode."""
        from .active import pair_disagreement

        scale = float(getattr(self.scorer, "return_scale", 1.0))
        with self.lock:
            answered = self._answered()
            counts = self._compared_counts(person, answered)
            need = sorted((e for e in self.episodes.values()
                           if counts.get(e.episode, 0) < self.comparisons_per_episode),
                          key=lambda e: e.finished_at)[: self.pair_window]
            pairs = []
            for i, x in enumerate(need):
                for y in need[i + 1:]:
                    key = (min(x.episode, y.episode), max(x.episode, y.episode))
                    if (person, *key) in self.cant or (person, *key) in answered:
                        continue
                    if self.assignment == "split" and any((p, *key) in answered for p in self.people):
                        continue
                    score = None
                    if x.members is not None and y.members is not None and len(x.members) > 1:
                        score = pair_disagreement(x.members, y.members, scale)
                    pairs.append((x.episode, y.episode, score, max(x.finished_at, y.finished_at)))
        pairs.sort(key=lambda q: (-(q[2] or 0.0), q[3]))
        return [(a, b, score) for a, b, score, _ in pairs[:limit]]

    @property
    def pair_ordering(self) -> str:
        from .active import PAIR_DISAGREEMENT

        members = getattr(self.scorer, "members", 1) if self.scorer is not None else 1
        return PAIR_DISAGREEMENT if members > 1 else "oldest pairs first"

    def compare(self, a: int, b: int, preference: str, person: str = "") -> tuple:
        """Record `person`'s answer on episodes a (left) and b (right): preference 'a', 'b' or
        'equal'; returns (Comparison, Episode a, Episode b)."""
        self._check_person(person)
        if not isinstance(preference, str) or preference not in PREFERENCES:
            raise LabelError(f"'preference' must be one of {', '.join(PREFERENCES)}, got {preference!r}")
        if a == b:
            raise LabelError("an episode cannot be compared with itself")
        ep_a, ep_b = self.get(a), self.get(b)
        key = (person, min(a, b), max(a, b))
        with self.lock:
            before = self.comparisons.get(key)
            record = Comparison(a, b, PREFERENCES[preference], time.time(),
                                0 if before is None else before.corrections + 1, person)
            self.comparisons[key] = record
            self.cant.discard(key)
        return record, ep_a, ep_b

    def cant_tell(self, a: int, b: int, person: str = "") -> None:
        """`person` cannot tell a and b apart: that pair is not offered to them again."""
        self._check_person(person)
        self.get(a), self.get(b)
        with self.lock:
            self.cant.add((person, min(a, b), max(a, b)))

    def needs_comparisons(self, episode: int) -> bool:
        """Someone is still to compare `episode` (split: fewer than comparisons_per_episode answers)."""
        with self.lock:
            answered = self._answered()
            return any(self._compared_counts(p, answered).get(episode, 0) < self.comparisons_per_episode
                       for p in self.people)

    def comparison_history(self, person: str | None = None) -> list:
        """The comparisons answered in this session (by `person`; None: by everyone), newest first."""
        with self.lock:
            return sorted((c for c in self.comparisons.values() if person is None or c.person == person),
                          key=lambda c: c.at, reverse=True)
