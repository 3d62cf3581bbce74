"""Is a trained reward model fit to train an agent on? The checks of `nmrm check`.

Low test MSEs are not enough (issue 34: a Charger model with a reward MSE of 0.0002 whose agents
failed, and a Key model whose agent was paid 87 for episodes the oracle scores ~50). Two checks
look at the model from the agent's side, on the model's task with its oracle:

1. **Memory** (`memory_check`): does the served state separate what the oracle's hidden state
   separates? From screened trajectories, take pairs of steps whose states (the privileged ones
   where the task has them: a pixel task's positions) are close (each
   coordinate within `state_tol` standard deviations) but whose oracle hidden states differ (by
   more than 10% of its standard deviation): an agent at those two steps observes
   [s_t, served_{t+1}], so if the two served states are (almost) equal it cannot tell the two
   situations apart, whatever rewards the model pays. A pair is *separated* when its served
   states are further apart than both `separation_tol` of the median distance between the served
   states of random pairs of steps and `min_distance` (0.01: a gate that shuts h' scales it
   towards 0, and a difference of 1e-6 is none for an agent). Reported for the served state and
   for h' alone.
2. **Reward hacking** (`hacking_check`): a short agent run on the model's reward (the task's
   algorithm, `episodes` episodes, seeded), then its greedy policy on new episodes: the learnt
   return the model pays against the oracle's return of the same episodes, beside the same gap on
   random-policy episodes. An agent finds the states where the model overpays; a gap far beyond
   the model's error on random episodes means it learnt the model's mistake.

A check passes when at least `min_separated` (90%) of the pairs are separated, and when the agent's
mean gap |learnt - oracle| is within max(3 x the model's return RMSE on random-policy episodes, 5%
of the oracle's return scale).

A model of comparisons that was not calibrated pays on a scale and with an offset of its own (Key,
4000 perfect comparisons: ~3.1 r + const per step of the oracle's r), so its learnt returns are
compared in the oracle's units: R' = a R + c is fitted by least squares on screened episodes of
the task (`units_map`), and the check reads (R' - c) / a. The offset is one constant per episode,
not per step: what the model pays per step (which an agent can earn by making episodes longer or
shorter) stays in the comparison. Without the map, every such model failed the check by its
scale alone; a model whose returns do not grow with the oracle's fails it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .model_check import AgentEpisodesCheck, gap_tolerance


@dataclass
class MemoryCheck:
    """pairs: close-state pairs whose oracle hidden states differ; separated: the fraction of them
    the served state separates (h_only: with h' alone; None without an LSTM)."""

    pairs: int
    separated: float
    h_only: float | None
    min_separated: float = 0.9
    oracle_hidden: bool = True  # False: the oracle gives no hidden state, so nothing can be checked

    @property
    def passed(self) -> bool:
        return self.pairs == 0 or self.separated >= self.min_separated

    def summary(self) -> str:
        if not self.oracle_hidden:
            return ("memory: not checked: the oracle returns no hidden state (return (rewards, hidden) "
                    "from it to check what the served state carries)")
        if self.pairs == 0:
            return "memory: no pairs of close states with different oracle hidden states (nothing to separate)"
        h = "" if self.h_only is None else f" (h' alone: {self.h_only:.0%})"
        verdict = "PASS" if self.passed else f"FAIL (below {self.min_separated:.0%})"
        return (f"memory: the served state separates {self.separated:.0%} of {self.pairs} pairs of close "
                f"states whose oracle hidden states differ{h}: {verdict}")


@dataclass
class UnitsMap:
    """A model's returns against the oracle's on screened episodes: R' = gain R + offset."""

    gain: float
    offset: float  # per episode
    episodes: int

    @property
    def usable(self) -> bool:
        """The model's returns grow with the oracle's (else they cannot be read in its units)."""
        return bool(np.isfinite(self.gain) and self.gain > 0)

    def oracle_units(self, learnt: np.ndarray) -> np.ndarray:
        return (np.asarray(learnt, float) - self.offset) / self.gain

    def summary(self) -> str:
        if not self.usable:
            return (f"the model learnt from comparisons, and its returns do not grow with the oracle's on "
                    f"{self.episodes} screened episodes (R' = {self.gain:.3g} R {self.offset:+.3g}): compared as "
                    f"they are")
        return (f"the model learnt from comparisons, so its returns are read in the oracle's units: "
                f"R' = {self.gain:.3g} R {self.offset:+.3g}, fitted on {self.episodes} screened episodes")


@dataclass
class HackingCheck:
    """Mean learnt and oracle returns of the greedy agent's episodes and of random-policy ones
    (learnt returns in the oracle's units where `units` maps them)."""

    agent_learnt: float
    agent_oracle: float
    random_learnt: float
    random_oracle: float
    random_rmse: float
    scale: float
    episodes: int
    units: UnitsMap | None = None

    @property
    def gap(self) -> float:
        return self.agent_learnt - self.agent_oracle

    @property
    def tolerance(self) -> float:
        return gap_tolerance(self.random_rmse, self.scale)

    @property
    def passed(self) -> bool:
        return abs(self.gap) <= self.tolerance and (self.units is None or self.units.usable)

    def summary(self) -> str:
        verdict = "PASS" if self.passed else "FAIL: the agent learnt where the model is wrong"
        units = "" if self.units is None else f" ({self.units.summary()})"
        return (f"reward hacking{units}: a short agent's greedy episodes are paid {self.agent_learnt:.2f} by the "
                f"model, {self.agent_oracle:.2f} by the oracle (gap {self.gap:+.2f}, tolerance "
                f"{self.tolerance:.2f}); random episodes {self.random_learnt:.2f} vs {self.random_oracle:.2f} "
                f"(return RMSE {self.random_rmse:.2f}): {verdict}")


def _close_pairs(states: np.ndarray, oracle: np.ndarray, state_tol: float, rows: int = 512):
    """Index pairs (i, j), i < j, of steps with close states and different oracle hidden states."""
    s = (states - states.mean(0)) / np.maximum(states.std(0), 1e-9)
    h = (oracle - oracle.mean(0)) / np.maximum(oracle.std(0), 1e-9)
    pairs = []
    for start in range(0, len(s), rows):
        block = slice(start, start + rows)
        close = np.all(np.abs(s[block, None] - s[None]) <= state_tol, axis=-1)
        differ = np.linalg.norm(h[block, None] - h[None], axis=-1) > 0.1
        i, j = np.nonzero(close & differ)
        i = i + start
        keep = i < j
        pairs.append(np.stack([i[keep], j[keep]], 1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), int)


def _separated(served: np.ndarray, pairs: np.ndarray, tol: float, min_distance: float, rng) -> float:
    a, b = rng.integers(0, len(served), (2, 4000))
    typical = np.median(np.linalg.norm(served[a] - served[b], axis=-1))
    d = np.linalg.norm(served[pairs[:, 0]] - served[pairs[:, 1]], axis=-1)
    return float(np.mean(d > max(tol * typical, min_distance)))


def screened_episodes(task: str, trajectories: int = 300, seed: int = 12345, oracle: str = ""):
    """The checks' episodes: `trajectories` screened episodes of `task` (data seed `seed`), labelled
    by `oracle` ("" = the task's own); a `TrajectoryDataset`."""
    from ..datasets import generate_screened

    return generate_screened(task, trajectories, seed=seed, oracle=oracle)


def memory_check(model, task: str, trajectories: int = 300, seed: int = 12345, steps: int = 4000,
                 state_tol: float = 0.05, separation_tol: float = 0.1,
                 min_distance: float = 0.01, oracle: str = "", screened=None) -> MemoryCheck:
    """The memory check on `trajectories` screened trajectories of `task` (data seed `seed`;
    `screened`: those already made by `screened_episodes`), `steps` steps drawn from them;
    `oracle`: a user's oracle function (its hidden state is what must be separated), "" = the
    task's own."""
    from ..mil.served_state import served_states
    from ..oracles import make_oracle

    judge = make_oracle(task, oracle)
    ds = screened if screened is not None else screened_episodes(task, trajectories, seed, oracle)
    # what the oracle sees (a pixel task: the privileged state), and where "close" is measured
    seen = ds.states if ds.privileged is None else ds.privileged
    labels = judge.label(seen, lengths=ds.lengths)
    if labels.hidden.shape[-1] == 0:
        return MemoryCheck(0, 0.0, None, oracle_hidden=False)
    oracle = labels.hidden
    real = np.argwhere(np.arange(ds.states.shape[1])[None, :] < ds.lengths[:, None])
    rng = np.random.default_rng(seed)
    pick = real[rng.choice(len(real), min(steps, len(real)), replace=False)]
    states = seen[pick[:, 0], pick[:, 1]].astype(np.float64)
    hidden = oracle[pick[:, 0], pick[:, 1]]
    pairs = _close_pairs(states, hidden, state_tol)
    served = served_states(model, ds.states, ds.lengths)
    if served.shape[-1] == 0:  # no recurrent state: nothing is separated beyond the state itself
        return MemoryCheck(len(pairs), 0.0, None)
    served = served[pick[:, 0], pick[:, 1]]
    k = served.shape[-1] // 2
    if len(pairs) == 0:
        return MemoryCheck(0, 1.0, 1.0)
    return MemoryCheck(len(pairs), _separated(served, pairs, separation_tol, min_distance, rng),
                       _separated(served[:, :k], pairs, separation_tol, min_distance, rng))


def units_map(model, task: str, trajectories: int = 300, seed: int = 12345, oracle: str = "",
              screened=None) -> UnitsMap:
    """R' = gain R + offset fitted by least squares on `trajectories` screened episodes of `task`
    (data seed `seed`; `screened`: those already made by `screened_episodes`): R' the model's
    return (its members' mean, as served), R the oracle's. A gain that is not positive (the model
    does not order the oracle's returns) makes the map unusable (`UnitsMap.usable`) and the check
    fail."""
    from ..mil.ensemble import as_ensemble
    from ..mil.evaluation import batched_outputs

    ds = screened if screened is not None else screened_episodes(task, trajectories, seed, oracle)
    learnt = np.concatenate([out.returns.mean(0).double().numpy()
                             for out, _ in batched_outputs(as_ensemble(model), ds)])
    (gain, offset), *_ = np.linalg.lstsq(np.stack([ds.returns, np.ones(len(ds.returns))], 1), learnt, rcond=None)
    return UnitsMap(float(gain), float(offset), len(ds.returns))


def hacking_check(checkpoint: str | Path, task: str, episodes: int = 150, eval_episodes: int = 50,
                  seed: int = 0, oracle: str = "", screened=None) -> HackingCheck:
    """The reward-hacking check: train an agent for `episodes` episodes on the checkpoint's reward
    (agent seed `seed`), then compare learnt and oracle returns of its greedy episodes (and of
    random ones) on `eval_episodes` new episodes; `oracle`: a user's oracle function, "" = the task's.
    On a task with a privileged state the agent observes it beside the served state. A model of
    comparisons is read in the oracle's units by `units_map` on `screened` (default: made here,
    data seed 12345 + seed, as the memory check's)."""
    from ..mil.checkpoint import load_checkpoint
    from ..tasks import task_info
    from .evaluation import EVAL_SEED, random_policy, run_episodes
    from .training import train_agent
    from .wrappers import make_reward_env

    # a task with a privileged state (a camera task): the agent sees it, not the pixels (an MLP
    # agent of pixels learns nothing, and a check by an agent that learns nothing passes anything)
    observe = "privileged" if task_info(task).privileged_size else "state"
    model, meta = load_checkpoint(checkpoint)
    units = None if meta.return_units else units_map(model, task, seed=12345 + seed, oracle=oracle, screened=screened)
    run = train_agent(task, "model", checkpoint, episodes=episodes, seed=seed, progress=False, oracle=oracle,
                      observe=observe)
    env = make_reward_env(task, "model", checkpoint, seed=EVAL_SEED, oracle=oracle, observe=observe)
    agent_o, agent_l = run_episodes(env, eval_episodes, EVAL_SEED,
                                    lambda obs: run.model.predict(obs, deterministic=True)[0])
    rand_o, rand_l = run_episodes(env, eval_episodes, EVAL_SEED, random_policy(env.action_space, seed))
    if units is not None and units.usable:
        agent_l, rand_l = units.oracle_units(agent_l), units.oracle_units(rand_l)
    scale = max(np.abs(agent_o).mean(), np.abs(rand_o).mean(), np.std(rand_o), 1e-9)
    return HackingCheck(float(agent_l.mean()), float(agent_o.mean()), float(rand_l.mean()),
                        float(rand_o.mean()), float(np.sqrt(np.mean((rand_l - rand_o) ** 2))),
                        float(scale), eval_episodes, units)


def next_step(results: list, checkpoint: str, task: str, oracle: str = "") -> str:
    """What to run when a check fails (printed by `nmrm check`): the reward-model <-> agent loop
    labels the agent's own episodes, where the model is wrong, with the same oracle; people do the
    same on the labelling page with the agent acting (label.launch.yaml policy:=learn)."""
    import shlex

    failed = [r for r in results if not r.passed]
    q = shlex.quote
    oracle_opt = f" --oracle {q(oracle)}" if oracle else ""
    loop = (f"nmrm loop --task {q(task)}{oracle_opt} --rounds 4 --labels-per-round 500 "
            f"--out runs/loop")
    people = (f"nmrm launch launch_scripts/label.launch.yaml task:={q(task)} checkpoint:={q(checkpoint)} "
              f"policy:=learn person:=NAME")
    lines = []
    if any(isinstance(r, (HackingCheck, AgentEpisodesCheck)) for r in failed):
        lines.append("next: the agent found where the model is wrong; label its own episodes so the model "
                     f"learns there (the reward-model <-> agent loop): {loop}")
        lines.append(f"      or label them yourself on the page while the agent learns: {people}")
    if any(isinstance(r, MemoryCheck) for r in failed):
        lines.append("next: the served state forgets what the oracle remembers; train on more (or longer) "
                     "labelled episodes, or with a larger hidden state (nmrm train --help), then check again; "
                     f"the loop also adds episodes where the agent goes: {loop}")
    return "\n".join(lines)
