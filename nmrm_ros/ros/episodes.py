"""Following episodes from the observation stream: the ordering rule every consumer applies.

For each EnvObservation, `EpisodeFollower.classify` says what it is for a consumer that must see
each episode's steps exactly once and in order:

- START: step 0 of an episode (any episode number): (re)starts that episode, unless it repeats
  the step 0 just seen (then DUPLICATE).
- NEXT: the next step of the current episode.
- DUPLICATE: the same (episode, step) again with the same state (env_sim re-publishes an
  observation when an action times out): answer as before, do not step again.
- BROKEN: anything else (a step skipped, a step from the past with another state, another
  episode without its step 0, a step after the final one): the current episode is broken; the
  consumer stops following it until the next step 0, and counts it.
"""

from __future__ import annotations

import enum

import numpy as np

from .messages import as_vector


class Kind(enum.Enum):
    START = "start"
    NEXT = "next"
    DUPLICATE = "duplicate"
    BROKEN = "broken"


class EpisodeFollower:
    def __init__(self) -> None:
        self.episode: int | None = None
        self.step = -1
        self.state: np.ndarray | None = None
        self.finished = False
        self.broken = False
        #: True if the last classify/break_episode call broke a so-far-intact episode
        self.just_broke = False
        #: episodes broken so far (each counted once)
        self.broken_episodes = 0

    def break_episode(self, episode: int) -> bool:
        """Mark `episode` broken (e.g. its state was invalid); True if it was not broken before."""
        newly = not (self.broken and self.episode == episode)
        self.episode, self.broken, self.just_broke = episode, True, newly
        self.broken_episodes += int(newly)
        return newly

    def classify(self, episode: int, step: int, state: np.ndarray) -> Kind:
        self.just_broke = False
        if step == 0 and (self.broken or not (episode == self.episode and self.step == 0
                                              and self._same(state))):
            self.episode, self.step, self.state = episode, 0, state
            self.finished = self.broken = False
            return Kind.START
        if self.broken or episode != self.episode:
            self.break_episode(episode)
            return Kind.BROKEN
        if step == self.step and self._same(state):
            return Kind.DUPLICATE
        if step == self.step + 1 and not self.finished:
            self.step, self.state = step, state
            return Kind.NEXT
        self.break_episode(episode)
        return Kind.BROKEN

    def follow(self, msg, task: str, state_size: int) -> tuple:
        """Validate an EnvObservation (task, state size, finite) and classify it.

        Returns (kind, state, why): state is the float64 state (None if invalid); why says what
        broke the episode when kind is BROKEN (log it when `just_broke`).
        """
        try:
            if msg.task != task:
                raise ValueError(f"observation of task {msg.task!r}, expected {task!r}")
            state = as_vector(msg.state, state_size, "state")
        except ValueError as exc:
            self.break_episode(msg.episode)
            return Kind.BROKEN, None, str(exc)
        kind = self.classify(msg.episode, msg.step, state)
        return kind, state, f"step {msg.step} out of order" if kind is Kind.BROKEN else ""

    def finish(self) -> None:
        """Mark the current episode complete (its final observation was consumed)."""
        self.finished = True

    def _same(self, state: np.ndarray) -> bool:
        return self.state is not None and self.state.shape == state.shape and bool(np.all(self.state == state))
