"""The labelled episodes a trainer has collected so far (no ROS).

Episodes (their states) and labels arrive separately and in any order; they join by episode id
and length, as in the labeller contract. The latest label per (labeller, episode) counts, so a
correction replaces the label it corrects; two labellers of one episode give two bags (each an
opinion on the same trajectory). Comparisons (TrajectoryPreference) join the same way, by both
episodes' ids and lengths; the latest answer per (labeller, pair) counts. An episode that is only
compared is one bag with return NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..datasets.trajectories import TrajectoryDataset


@dataclass
class TrainingSet:
    task: str
    state_size: int
    max_episodes: int = 20000                          # oldest episodes forgotten beyond this
    episodes: dict = field(default_factory=dict)       # episode id -> states (L, d) float32
    final: dict = field(default_factory=dict)          # episode id -> final observation (d,)
    labels: dict = field(default_factory=dict)         # (labeller, episode) -> (return, length, stamp ns)
    comparisons: dict = field(default_factory=dict)    # (labeller, min, max) -> (a, length a, b, length b, p, stamp ns)
    source: str = ""                                   # the namespace the episodes and labels come from

    def add_episode(self, episode: int, states: np.ndarray) -> None:
        """A finished episode: states (L + 1, d), the final observation last."""
        states = np.asarray(states, np.float32)
        self.episodes[int(episode)] = states[:-1]
        self.final[int(episode)] = states[-1]
        while len(self.episodes) > self.max_episodes:
            oldest = next(iter(self.episodes))
            del self.episodes[oldest], self.final[oldest]

    def add_label(self, labeller: str, episode: int, length: int, value: float, stamp_ns: int = 0) -> bool:
        """Record a label given at `stamp_ns` (a later one of the same labeller and episode
        replaces it); True if it is new rather than a correction."""
        key = (str(labeller), int(episode))
        new = key not in self.labels
        self.labels[key] = (float(value), int(length), int(stamp_ns))
        return new

    def add_comparison(self, labeller: str, a: int, length_a: int, b: int, length_b: int, p: float,
                       stamp_ns: int = 0) -> bool:
        """Record a comparison (p = P(a better)); True if the pair is new for this labeller."""
        key = (str(labeller), min(int(a), int(b)), max(int(a), int(b)))
        new = key not in self.comparisons
        self.comparisons[key] = (int(a), int(length_a), int(b), int(length_b), float(p), int(stamp_ns))
        return new

    def _here(self, episode: int, length: int) -> bool:
        return episode in self.episodes and len(self.episodes[episode]) == length

    def joined_comparisons(self) -> list:
        """[(a, b, p)] of the comparisons whose both episodes are here with the lengths compared."""
        return [(a, b, p) for (a, la, b, lb, p, _) in (self.comparisons[k] for k in sorted(self.comparisons))
                if self._here(a, la) and self._here(b, lb)]

    def comparison_records(self) -> list:
        """The joined comparisons as provenance records (bags.label_records.comparison_record)."""
        from ..bags.label_records import comparison_record

        return [comparison_record(self.task, self.source, a, la, b, lb, p, lab, stamp)
                for (lab, _, _), (a, la, b, lb, p, stamp) in sorted(self.comparisons.items())
                if self._here(a, la) and self._here(b, lb)]

    def joined(self) -> list:
        """[(labeller, episode, return)] of the labels whose episode is here with the same length."""
        return [(lab, ep, value) for (lab, ep), (value, length, _) in sorted(self.labels.items())
                if ep in self.episodes and len(self.episodes[ep]) == length]

    def dataset(self) -> TrajectoryDataset:
        """The joined labels as MIL bags (no oracle rewards: `rewards` and `hidden` are zeros)."""
        rows = self.joined()
        compared = self.joined_comparisons()
        labelled = {ep for _, ep, _ in rows}
        rows += [("", ep, float("nan")) for ep in sorted({e for a, b, _ in compared for e in (a, b)} - labelled)]
        if not rows:
            raise ValueError("no labelled episode yet")
        n, horizon = len(rows), max(len(self.episodes[ep]) for _, ep, _ in rows)
        states = np.zeros((n, horizon, self.state_size), np.float32)
        lengths = np.zeros(n, np.int64)
        for i, (_, ep, _) in enumerate(rows):
            lengths[i] = len(self.episodes[ep])
            states[i, :lengths[i]] = self.episodes[ep]
        final = np.stack([self.final[ep] for _, ep, _ in rows])
        returns = np.array([v for _, _, v in rows], np.float64)
        from ..bags.label_records import label_record

        meta = {"source": "live labels", "episodes": [ep for _, ep, _ in rows],
                "sources": [self.source] * n,
                "labels": [label_record(self.task, self.source, ep, lengths[i], value, lab,
                                        self.labels[(lab, ep)][2] if lab else 0)
                           for i, (lab, ep, value) in enumerate(rows)],
                "labellers": sorted({lab for lab, _, _ in rows if lab}), "oracle_ground_truth": False,
                "comparisons": self.comparison_records()}
        row_of: dict = {}
        for i, (_, ep, _) in enumerate(rows):
            row_of.setdefault(ep, i)
        prefs = (np.array([(row_of[a], row_of[b], p) for a, b, p in compared], np.float64)
                 if compared else None)
        return TrajectoryDataset(self.task, states, lengths, returns, np.zeros((n, horizon)),
                                 np.zeros((n, horizon, 0)), final_states=final, meta=meta, preferences=prefs)
