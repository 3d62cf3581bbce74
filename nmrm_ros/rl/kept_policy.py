"""Which policy of a run is kept: the best one seen, not whatever the last step left.

An off-policy agent can learn a task and lose it again (issue 50: a DQN agent on an accurate reward
model earned 163 an episode, then its values ran away and its greedy policy earned 0). The policy
that is saved as `policy.zip` is therefore the best *snapshot* of the run; the last one is saved
beside it (`last_policy.zip`).

Every `every` episodes the policy's weights are copied (a snapshot), and the snapshot is scored by
the `every` episodes that follow it (those it, and its next few updates, acted in: no extra
episodes are run, so an agent learning through the ROS graph is scored the same way). An
episode's score is

    min(learnt return, judged return), each scaled to [0, 1] by its min and max over the run,

where the judged return is the labeller's or oracle's return of that episode when the run has one
(`nmrm rl train` and the loop always do; the agent node when a labeller publishes), else the learnt
return alone. So a policy is kept for being good by the reward model *and* by the judge: a model
that overpays the states an agent found (reward hacking) cannot make its policy kept on its own,
and neither can a judge's lucky episodes under a policy the model rates low. A window whose
agent's values left the bound the rewards allow (`value_bound`; by more than 1% of the run's
largest bound, as `collapse.beyond_bound` judges) is not scored: its policy was bootstrapping on
nothing.

The kept snapshot is the latest whose score is within `tolerance` (0.05 on that scale) of the
best: in a run that does not collapse that is (nearly) the last policy, as before; when the last
scored window is the kept one, the last policy itself is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .collapse import beyond_bound

#: what the score of a snapshot is (written to agent.json)
CRITERION = ("mean over the episodes after a snapshot of min(learnt, judged), each return scaled to [0, 1] "
             "over the run (learnt alone where no judge labels); windows with max Q beyond the value bound not scored")


@dataclass
class Snapshot:
    episode: int   # the policy as it was after `episode` episodes (it acted in the next ones)
    weights: dict  # a copy of policy.state_dict()
    tag: str | None = None  # what served its observations and rewards (the loop: the checkpoint)
    score: float = -math.inf  # set by PolicyKeeper.kept()


def _scaled(values: np.ndarray) -> np.ndarray:
    """values scaled to [0, 1] by their finite min and max over the run (nan stays nan)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return values
    lo, hi = finite.min(), finite.max()
    return (values - lo) / (hi - lo) if hi > lo else np.where(np.isfinite(values), 1.0, np.nan)


def episode_scores(learnt: np.ndarray, judged: np.ndarray) -> np.ndarray:
    """Per episode min(scaled learnt, scaled judged), or the scaled learnt return where there is
    no judgement (nan). Scaling each over the run makes the two comparable whatever their units
    (a model of comparisons pays in its own)."""
    a, b = _scaled(np.asarray(learnt, float)), _scaled(np.asarray(judged, float))
    return np.where(np.isfinite(b), np.minimum(a, b), a)


class PolicyKeeper:
    """Snapshots an SB3 model's policy every `every` episodes and keeps the best (module docstring).

    Call `on_episode(model, learnt, judged, q_max, bound_high)` once per finished episode (in the
    order they finish); `set_judged(i, value)` for a judgement that arrives later (a labeller's);
    then `kept()` for the snapshot to save (None: the last policy is the one to keep).
    When the reward model the agent observes is swapped (the loop), `retag(checkpoint, model)`: a
    policy is kept together with the model it acted on (`Snapshot.tag`), and no window spans two.
    """

    def __init__(self, every: int = 20, tolerance: float = 0.05) -> None:
        if every < 1:
            raise ValueError(f"a policy snapshot every {every} episodes: must be at least 1")
        self.every = int(every)
        self.tolerance = float(tolerance)
        self.snapshots: list[Snapshot] = []
        self.learnt: list = []
        self.judged: list = []
        self.q_bound: list = []  # per episode: (mean max Q, the value bound's top then), None where unknown
        self.tag: str | None = None

    @property
    def episodes(self) -> int:
        return len(self.learnt)

    def on_episode(self, model, learnt: float, judged: float = math.nan, q_max: float | None = None,
                   bound_high: float | None = None) -> None:
        self.learnt.append(float(learnt))
        self.judged.append(float(judged))
        self.q_bound.append((q_max, bound_high))
        if self.episodes % self.every == 0:
            self.snapshots.append(Snapshot(self.episodes, _copy_weights(model), self.tag))

    def retag(self, tag: str, model) -> None:
        """From now on the policy acts on `tag` (a new reward model): a snapshot whose window is
        not complete is dropped, and the policy is snapshotted again under the new tag."""
        self.tag = tag
        self.snapshots = [s for s in self.snapshots if s.episode + self.every <= self.episodes]
        self.snapshots.append(Snapshot(self.episodes, _copy_weights(model), tag))

    def set_judged(self, episode: int, value: float) -> None:
        if 0 <= episode < self.episodes:
            self.judged[episode] = float(value)

    def _score(self) -> list:
        """The snapshots with a full window, their `score` set (-inf: Q beyond the bound)."""
        scores = episode_scores(np.array(self.learnt), np.array(self.judged))
        bounds = [abs(b) for _, b in self.q_bound if b is not None and math.isfinite(b)]
        scale = max(bounds) if bounds else None  # the margin is of the run's scale (collapse.beyond_bound)
        beyond = [beyond_bound(q, b, scale) for q, b in self.q_bound]
        scored = []
        for s in self.snapshots:
            window = slice(s.episode, s.episode + self.every)
            if s.episode + self.every > self.episodes:
                continue
            s.score = -math.inf if any(beyond[window]) else float(np.mean(scores[window]))
            scored.append(s)
        return scored

    def kept(self) -> Snapshot | None:
        """The latest snapshot scored within `tolerance` (of the scaled range) of the best; None
        when no window is scored, or when the kept window is the last one (the last policy, a
        little further trained, is kept then)."""
        scored = [s for s in self._score() if np.isfinite(s.score)]
        if not scored:
            return None
        best = max(s.score for s in scored)
        keep = [s for s in scored if s.score >= best - self.tolerance][-1]
        last_window = max(s.episode for s in self.snapshots if s.episode + self.every <= self.episodes)
        return None if keep.episode == last_window else keep

    def summary(self) -> dict:
        """For agent.json: the criterion, the kept policy's episode and score, the best and last."""
        keep = self.kept()
        scored = self._score()
        finite = [s.score for s in scored if np.isfinite(s.score)]
        return {"criterion": CRITERION, "every": self.every,
                "episode": keep.episode if keep is not None else self.episodes,
                "tag": keep.tag if keep is not None else self.tag,
                "is_last": keep is None,
                "score": keep.score if keep is not None else (scored[-1].score if scored else None),
                "best_score": max(finite) if finite else None,
                "windows_beyond_bound": sum(1 for s in scored if not np.isfinite(s.score))}


def _copy_weights(model) -> dict:
    return {k: v.detach().cpu().clone() for k, v in model.policy.state_dict().items()}
