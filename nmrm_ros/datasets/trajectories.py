"""`TrajectoryDataset`: a batch of labelled trajectories (MIL bags) held in padded arrays."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np


#: meta entries that are lists with one item per trajectory (kept aligned by subset and concatenate):
#: the episode id, its source (a namespace) and its label's provenance record (who, what, when)
PER_TRAJECTORY_META = ("episodes", "sources", "labels")


@dataclass
class TrajectoryDataset:
    """n trajectories padded to length L (padding is zero; `lengths` says what is real).

    states (n, L, d) float32: the instances s_0..s_{len-1} (uint8 where the task's state is an
    image's pixels, `TaskInfo.image_shape`: 4x smaller); final_states (n, d), same dtype: the
    observation s_len after the last action (None for toy bags); actions (n, L) int64 or
    (n, L, m) float32, or None; returns (n,) float64 (the labels); rewards (n, L) float64 and
    hidden (n, L, k) float64: the oracle's r_t and h_{t+1} (evaluation only); classes (n,) int64
    screening class ids or None; meta: seed, draws, timing and other facts of generation.
    preferences (m, 3) float64 or None: pairwise comparisons of trajectories, one row
    (a, b, p) per comparison: indices a and b into this dataset and p = P(a better than b) as
    labelled (1: a better, 0: b better, 0.5: equal). A trajectory without a return label (only
    compared) has return NaN. privileged (n, L, p) float32 or None: the privileged state at each
    step (what the oracle saw and a model never sees, `TaskInfo.privileged_size`).
    """

    task: str
    states: np.ndarray
    lengths: np.ndarray
    returns: np.ndarray
    rewards: np.ndarray
    hidden: np.ndarray
    actions: np.ndarray | None = None
    final_states: np.ndarray | None = None
    classes: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    preferences: np.ndarray | None = None
    privileged: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.states.shape[0])

    @property
    def state_size(self) -> int:
        return int(self.states.shape[2])

    def subset(self, index: np.ndarray) -> "TrajectoryDataset":
        """The trajectories at `index` (an int array or bool mask), in that order; the meta lists
        with one entry per trajectory (PER_TRAJECTORY_META) are picked alike."""
        pick = lambda a: None if a is None else a[index]  # noqa: E731
        rows = np.arange(len(self))[index]
        meta = dict(self.meta)
        for key in PER_TRAJECTORY_META:
            if isinstance(meta.get(key), list) and len(meta[key]) == len(self):
                meta[key] = [meta[key][i] for i in rows]
        return TrajectoryDataset(self.task, self.states[index], self.lengths[index],
                                 self.returns[index], self.rewards[index], self.hidden[index],
                                 pick(self.actions), pick(self.final_states), pick(self.classes), meta,
                                 self._preferences_of(rows), pick(self.privileged))

    def _preferences_of(self, rows: np.ndarray) -> np.ndarray | None:
        """The comparisons between trajectories of `rows` (both ends picked), re-indexed into the
        subset's order; None without preferences."""
        if self.preferences is None:
            return None
        new = np.full(len(self), -1, dtype=np.int64)
        new[rows] = np.arange(len(rows))
        a, b = self.preferences[:, 0].astype(np.int64), self.preferences[:, 1].astype(np.int64)
        keep = (new[a] >= 0) & (new[b] >= 0)
        return np.column_stack([new[a[keep]], new[b[keep]], self.preferences[keep, 2]]).astype(np.float64)

    def deduplicated(self) -> tuple["TrajectoryDataset", int]:
        """(this dataset without repeated episodes, how many were dropped). Two episodes are the
        same when their states (s_0..s_len, the final observation included) and their label are
        equal, bit for bit (so two compared-only episodes, return NaN, are the same too); the first
        one is kept, and a comparison that named a dropped copy names the kept one. Used where
        bags from different sources are merged, so that one episode cannot be in both the training
        and the test split."""
        first: dict = {}
        same_as = np.arange(len(self), dtype=np.int64)  # each episode -> its first copy
        for i in range(len(self)):
            n = int(self.lengths[i])
            key = (self.states[i, :n].tobytes(), self.returns[i].tobytes(),
                   None if self.final_states is None else self.final_states[i].tobytes())
            same_as[i] = first.setdefault(key, i)
        keep = np.flatnonzero(same_as == np.arange(len(self)))
        if len(keep) == len(self):
            return self, 0
        source = self
        if self.preferences is not None:
            prefs = self.preferences.copy()
            prefs[:, 0] = same_as[prefs[:, 0].astype(np.int64)]
            prefs[:, 1] = same_as[prefs[:, 1].astype(np.int64)]
            source = replace(self, preferences=prefs[prefs[:, 0] != prefs[:, 1]])
        return source.subset(keep), len(self) - len(keep)

    def save(self, path: str | Path) -> Path:
        """Write an .npz (arrays) with the task and meta as JSON inside. Written to a temporary
        file first and renamed, so a reader (or a second writer of the same cache file) never
        sees half a file. ".npz" is appended to a path without it, as numpy does."""
        path = Path(path)
        if not path.name.endswith(".npz"):
            path = path.with_name(path.name + ".npz")
        arrays = {k: getattr(self, k) for k in ("states", "lengths", "returns", "rewards", "hidden",
                                                "actions", "final_states", "classes", "preferences",
                                                "privileged")
                  if getattr(self, k) is not None}
        header = json.dumps({"task": self.task, "meta": self.meta})
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        try:
            np.savez_compressed(tmp, _header=np.array(header), **arrays)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "TrajectoryDataset":
        with np.load(Path(path), allow_pickle=False) as z:
            header = json.loads(str(z["_header"]))
            get = lambda k: z[k] if k in z.files else None  # noqa: E731
            return cls(header["task"], z["states"], z["lengths"], z["returns"], z["rewards"],
                       z["hidden"], get("actions"), get("final_states"), get("classes"),
                       header["meta"], get("preferences"), get("privileged"))


def concatenate(parts: list, meta: dict | None = None) -> TrajectoryDataset:
    """One dataset of `parts` (same task and state size) in order, padded to the longest length;
    an optional field (actions, final_states, classes) is kept only if every part has it; the
    parts' preferences are all kept, re-indexed (a comparison is within one part)."""
    if not parts:
        raise ValueError("nothing to concatenate")
    width = max(p.states.shape[1] for p in parts)

    def cat(name: str):
        arrays = [getattr(p, name) for p in parts]
        if any(a is None for a in arrays):
            return None
        if name in ("states", "rewards", "hidden", "actions", "privileged"):
            arrays = [np.pad(a, [(0, 0), (0, width - a.shape[1])] + [(0, 0)] * (a.ndim - 2))
                      for a in arrays]
        return np.concatenate(arrays)

    if meta is None:
        meta = dict(parts[0].meta)
        for key in PER_TRAJECTORY_META:  # kept only if every part has it, one item per trajectory
            lists = [p.meta.get(key) for p in parts]
            if all(isinstance(x, list) and len(x) == len(p) for x, p in zip(lists, parts)):
                meta[key] = [item for x in lists for item in x]
            else:
                meta.pop(key, None)
    offsets = np.cumsum([0] + [len(p) for p in parts[:-1]])
    prefs = [p.preferences + np.array([o, o, 0.0]) for p, o in zip(parts, offsets) if p.preferences is not None]
    return TrajectoryDataset(parts[0].task, cat("states"), cat("lengths"), cat("returns"),
                             cat("rewards"), cat("hidden"), cat("actions"), cat("final_states"),
                             cat("classes"), meta, np.concatenate(prefs) if prefs else None, cat("privileged"))
