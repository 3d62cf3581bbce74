"""Did learning collapse? The one line `nmrm rl train` and the agent node end with.

Two signs, from a run's learning curve (`LearningCurve`) and its agent's value bound:

- **late dip**: over windows of `window` consecutive episodes (50, or a quarter of a shorter run),
  a window in the second half whose mean return fell back by more than half of what the run had
  gained before it (gain: the best earlier window's mean minus the first window's), or that fell
  below the first window's mean by more than its noise (a run that learnt within its first window).
  A gain within the noise of the first window (at most `NOISE_SES` standard errors of its mean) is
  no learning: a run that never learnt did not collapse, it is reported as not having learnt. Judged on the
  oracle's (labeller's) return where the curve has one, else on the learnt return.
- **values beyond their bound**: an episode whose mean max_a Q left the bound that the rewards
  allowed at that episode (`value_bound`; the curve's `value_bound`, which changes as rewards
  enter and leave the replay buffer and when the loop swaps the model) by more than 1% of the
  largest bound of the run (`BOUND_MARGIN`). A curve without per-episode bounds is judged against
  the one bound given (the end of the run's). The margin is of the run's scale, not the
  episode's: in the first episodes the buffer holds few rewards and their bound can be far below
  the values a network outputs before it has learnt anything (patrol robot, a model paying
  ~2e-4 a step at first: bound 0.02 at episode 0, the untrained network's Q 0.07; the run's
  bound 100), which is not a value running away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a gain of at most this many standard errors of the first window's mean is noise, not learning
#: (the random episodes of Key's first 50: mean 0.56, standard error 0.34; a run whose best window
#: earned 1.52 had learnt nothing)
NOISE_SES = 4.0
#: values beyond their bound: by more than this fraction of the run's largest bound
BOUND_MARGIN = 0.01


def beyond_bound(q: float | None, bound: float | None, scale: float | None = None) -> bool:
    """Whether a mean max Q `q` left the value bound's top `bound` in force at its episode by more
    than BOUND_MARGIN of `scale` (the run's largest bound; None: `bound` itself)."""
    if q is None or bound is None or not np.isfinite(bound):
        return False
    scale = abs(bound) if scale is None or not np.isfinite(scale) else max(abs(scale), abs(bound))
    return q > bound + BOUND_MARGIN * scale + 1e-6


@dataclass
class CollapseReport:
    """dip: (best earlier window mean, its first episode, lowest later window mean, its first
    episode) or None; q_peak: the episode mean of max Q that went furthest beyond its bound, or,
    if none did, the largest (`peak_against_bound`; None: not a value-based agent); bound_high: the value bound's upper end at
    that episode (None: unbounded); q_episode: that episode (None: not known); judged_by: "oracle" |
    "learnt"."""

    dip: tuple | None
    q_peak: float | None
    bound_high: float | None
    judged_by: str
    window: int
    kept_episode: int | None = None  # the kept policy's snapshot (None: the last policy)
    best: tuple | None = None  # (best window mean, its first episode, the first window's mean); None: no window
    learnt: bool = True  # the best window beyond the noise of the first (see NOISE_SES)
    q_episode: int | None = None
    bound_scale: float | None = None  # the run's largest bound (None: bound_high)

    @property
    def q_beyond_bound(self) -> bool:
        return beyond_bound(self.q_peak, self.bound_high, self.bound_scale)

    @property
    def collapsed(self) -> bool:
        return self.dip is not None or self.q_beyond_bound

    def _against_bound(self) -> str:
        """How a max Q that did not run away stands against its bound: within it, or above it by
        less than the margin (BOUND_MARGIN of the run's largest bound)."""
        if self.bound_high is None:
            return ""
        if self.q_peak <= self.bound_high + 1e-6:
            return f" within its bound {self.bound_high:.3g}"
        scale = self.bound_high if self.bound_scale is None else self.bound_scale
        return (f" above its bound then ({self.bound_high:.3g}) by less than {BOUND_MARGIN:.0%} of the "
                f"run's largest bound ({scale:.3g}): not a runaway")

    def summary(self) -> str:
        kept = ("the last policy is kept" if self.kept_episode is None
                else f"kept the policy of episode {self.kept_episode} (policy.zip; the last: last_policy.zip)")
        at = "" if self.q_episode is None else f" (episode {self.q_episode})"
        q = "" if self.q_peak is None else f", max Q {self.q_peak:.3g}{at}" + self._against_bound()
        if not self.collapsed and not self.learnt and self.best is not None:
            best, at, first = self.best
            return (f"did not learn: the best {self.window} episodes' {self.judged_by} return ({best:.3g}, "
                    f"episodes {at}-{at + self.window - 1}) is within the noise of the first {self.window}'s "
                    f"({first:.3g}){q}; {kept}")
        if not self.collapsed:
            return f"no collapse: no late dip in the {self.judged_by} return{q}; {kept}"
        parts = []
        if self.dip is not None:
            best, at, low, low_at = self.dip
            parts.append(f"the {self.judged_by} return fell from {best:.3g} (episodes {at}-{at + self.window - 1}) "
                         f"to {low:.3g} (episodes {low_at}-{low_at + self.window - 1})")
        if self.q_beyond_bound:
            at = "" if self.q_episode is None else f" at episode {self.q_episode}"
            parts.append(f"max Q reached {self.q_peak:.3g}{at}, beyond the {self.bound_high:.3g} the rewards allow"
                         + ("" if self.q_episode is None else "ed then"))
        return "learning collapsed: " + "; ".join(parts) + f"; {kept}"

    def to_dict(self) -> dict:
        return {"collapsed": self.collapsed, "late_dip": self.dip, "q_peak": self.q_peak,
                "value_bound": self.bound_high, "q_episode": self.q_episode, "q_beyond_bound": self.q_beyond_bound,
                "judged_by": self.judged_by, "window": self.window, "learnt": self.learnt,
                "summary": self.summary()}


def _windows(values: np.ndarray, window: int) -> np.ndarray:
    return np.convolve(values, np.ones(window) / window, mode="valid")


def noise_of_first(returns: np.ndarray, window: int) -> float:
    """What the best window must gain over the first to count as learning: `NOISE_SES` standard
    errors of the first window's mean (its returns' standard deviation / sqrt(window))."""
    return NOISE_SES * float(np.std(returns[:window])) / np.sqrt(window)


def best_window(returns, window: int) -> tuple | None:
    """(best window mean, its start, the first window's mean), or None for a run shorter than a window."""
    returns = np.asarray(returns, dtype=float)
    if len(returns) < window:
        return None
    means = _windows(returns, window)
    at = int(np.argmax(means))
    return float(means[at]), at, float(means[0])


def late_dip(returns, window: int) -> tuple | None:
    """(best earlier mean, its start, lowest later mean, its start) of the first window in the
    second half that lost more than half the gain before it, or that fell below the first window
    by more than its noise (`noise_of_first`); else None. A gain within that noise is not one."""
    returns = np.asarray(returns, dtype=float)
    n = len(returns)
    if n < 2 * window:
        return None
    means = _windows(returns, window)
    first, noise = means[0], noise_of_first(returns, window)
    for start in range(max(n // 2, window), len(means)):
        earlier = means[: start - window + 1]  # windows that end before this one starts
        if earlier.size == 0:
            continue
        best_at = int(np.argmax(earlier))
        gain = earlier[best_at] - first
        if (gain > noise and means[start] < first + 0.5 * gain) or means[start] < first - max(noise, 1e-9):
            low_at = start + int(np.argmin(means[start:]))
            return float(earlier[best_at]), best_at, float(means[low_at]), low_at
    return None


def peak_against_bound(records, bound_high: float | None = None) -> tuple:
    """(q, bound, episode, scale) of the episode whose mean max Q went furthest beyond the bound in
    force then (its record's q["value_bound"]; `beyond_bound`), or, if none did, of the largest
    mean max Q, and the run's largest bound (the margin's scale: BOUND_MARGIN); records without
    their own bound are judged against `bound_high` (episode None: no record has its own).
    (None, bound_high, None, bound_high) when no record has a Q."""
    rows = [(r.q["q_max"], r.q.get("value_bound"), r.episode) for r in records
            if r.q and np.isfinite(r.q.get("q_max", np.nan))]
    if not rows:
        return None, bound_high, None, bound_high
    own = [b is not None and np.isfinite(b) for _, b, _ in rows]
    # a record without its own bound (the first episodes, before any training step) is judged by the given one
    bounded = [(q, b if has else bound_high, e) for (q, b, e), has in zip(rows, own) if has or bound_high is not None]
    if not bounded:  # an unbounded agent
        return max(q for q, _, _ in rows), None, None, None
    scale = max(abs(b) for _, b, _ in bounded)
    beyond = [row for row in bounded if beyond_bound(row[0], row[1], scale)]
    q, bound, episode = (max(beyond, key=lambda row: row[0] - row[1]) if beyond
                         else max(bounded, key=lambda row: row[0]))
    return q, bound, episode if any(own) else None, scale


def collapse_report(curve, bound_high: float | None = None, kept_episode: int | None = None,
                    window: int = 50) -> CollapseReport:
    """The report for a `LearningCurve` (its records' oracle_return, learnt_return and q: q_max and,
    where recorded, the value bound of that episode) and the agent's value bound at the end of the
    run (`ValueBound.high`, None for none)."""
    records = curve.records
    window = max(1, min(window, len(records) // 4))
    oracle = np.array([r.oracle_return for r in records], dtype=float)
    judged_by = "oracle" if len(oracle) and np.isfinite(oracle).all() else "learnt"
    returns = oracle if judged_by == "oracle" else np.array([r.learnt_return for r in records], float)
    q_peak, bound, q_episode, scale = peak_against_bound(records, bound_high)
    best = best_window(returns, window)
    learnt = best is None or best[0] - best[2] > noise_of_first(returns, window)
    return CollapseReport(late_dip(returns, window), q_peak, bound, judged_by, window, kept_episode, best,
                          learnt, q_episode, scale)
