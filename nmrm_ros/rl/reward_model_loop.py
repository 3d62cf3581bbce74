"""The reward-model ⇄ agent loop (the paper's Sec. 6 future work: "an iterative bootstrapping
approach with multiple RL + RM training iterations").

`run_loop(task, rounds, labels_per_round)` alternates labelling, MIL training and RL:

- round 0: `labels_per_round` screened random episodes (data seed `seed`, as `nmrm dataset
  screen`) are labelled by the oracle and model 0 is trained on them;
- round k >= 1: the agent (as it is after k/R of its episodes) acts for `labels_per_round` new
  episodes with its exploration policy (DQN: epsilon-greedy at its current epsilon; SAC: its
  stochastic policy), served by model k - 1; the oracle labels them, and model k is trained on
  all the labels so far, warm-started from model k - 1 (`nmrm_ros.mil.retrain`, no bootstrap);
- the agent learns for `episodes` episodes in one SB3 `learn()` call (its exploration schedule
  is that of one run), on model k during episodes [k E / R, (k + 1) E / R).

When the model changes, the agent's augmented state [s_t, h'_{t+1}] and its rewards change meaning.
The loop keeps the agent's networks (a warm start) and relabels its whole replay buffer with the
new model (`replay_relabel`): every stored episode is stepped through the new model from its first
state, so the agent learns only from the new model's rewards and hidden states; the episode that
has just started is re-stepped too (`RewardModelWrapper.swap_model`). Before it acts on the new
model, the agent's networks are refitted on the relabelled buffer (`catch_up_steps` gradient
steps, config/rl.yaml): without it the policy fitted to the old model's hidden units was
arbitrary on the new ones. A model's served state must
keep its size across rounds (the same architecture and hidden size: the task's config).

With `rounds=1` it is the offline baseline: one screened random dataset of `labels_per_round`
labels, one model, one agent.

`feedback="preferences"` (or `"both"`): a simulated teacher (`SimulatedTeacher`, B-Pref's knobs)
compares instead of labelling returns. Each round still collects `labels_per_round` episodes and
asks `labels_per_round` comparisons: round 0 pairs the screened episodes with each other; round k
pairs each new episode in turn with an episode drawn uniformly from all collected so far (old or
new), so the comparisons reach the returns the agent now earns: a model of comparisons fixes the
order of the returns it has seen compared, and only that (docs/guide/preferences.md, "Agents on a
model of comparisons"). The models train on all comparisons so far (`retrain(feedback=...)`); the
episodes' true returns stay in labels.npz as ground truth (used for training only with `both`).

Output in `out/`: labels.npz (every label, in order; round r's are rows [r N, (r + 1) N)),
model_r.{pt,json} per round, agent/ (policy.zip, curve.csv, agent.json as `nmrm rl train`'s) and
loop.json (per round: labels, training summary, the agent's episodes and their mean oracle return;
the final oracle return and a greedy evaluation of the kept policy, `agent/policy.zip`, with the
model it acted on, `kept_checkpoint`; the agent's collapse report; the last model's check).

The loop ends by checking its last model where the agent went (`last_model_check`): what it paid the
agent's last (up to 50) training episodes against the oracle's returns of the same episodes, with
`nmrm check`'s tolerance (`model_check.gap_tolerance`). The kept policy is chosen by min(learnt,
judged) and survives a model that overpays it; the model does not, and a FAIL says so.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .training import EpisodeCurveCallback

#: episode seeds of the agent's labelled episodes: well away from its training episodes' (seed + e)
LABEL_SEED_OFFSET = 10**7


@dataclass
class Round:
    """One round: its labels, its model, the agent episodes it served."""

    index: int
    labels: int            # labels collected this round (feedback preferences: comparisons answered)
    total_labels: int      # labels the model was trained on (comparisons, for preferences)
    source: str            # "screened random episodes" or "agent episodes"
    checkpoint: str
    training: dict         # nmrm_ros.mil.retrain summary
    first_episode: int = 0  # the agent's episodes served by this round's model: [first, last)
    last_episode: int = 0
    mean_oracle_return: float = float("nan")  # of those episodes
    label_mean_return: float = float("nan")   # of the episodes labelled this round
    seconds: float = 0.0


@dataclass
class LoopResult:
    task: str
    rounds: list = field(default_factory=list)
    final_oracle_return: float = float("nan")  # mean of the agent's last 50 training episodes
    greedy_oracle_return: float = float("nan")  # greedy policy on 50 new episodes
    seconds: float = 0.0
    out: str = ""
    feedback: str = "returns"
    collapse: str = ""         # the agent's collapse report (`nmrm_ros.rl.collapse`)
    collapsed: bool = False    # that report found a late dip or Q beyond its bound
    kept_checkpoint: str = ""  # the model the kept policy (agent/policy.zip) acted on
    last_model_check: str = ""   # last_model_verdict() ("" with comparisons: other units)
    last_model_agrees: bool | None = None  # that check passed (None: not made)

    def summary(self) -> str:
        prefs = self.feedback == "preferences"
        lines = [f"{'round':>5s} {'pairs' if prefs else 'labels':>7s} {'from':>26s} "
                 f"{'val pref. acc.' if prefs else 'val return MSE':>15s} "
                 f"{'agent episodes':>15s} {'oracle return':>14s}"]
        for r in self.rounds:
            lines.append(f"{r.index:5d} {r.total_labels:7d} {r.source:>26s} "
                         f"{r.training.get('val_preference_accuracy' if prefs else 'val_return_mse', float('nan')):15.4f} "
                         f"{f'{r.first_episode}-{r.last_episode - 1}':>15s} {r.mean_oracle_return:14.3f}")
        lines.append(f"final oracle return (last 50 episodes) {self.final_oracle_return:.3f}; greedy policy "
                     f"on 50 new episodes {self.greedy_oracle_return:.3f}; {self.seconds:.0f} s")
        if self.collapse:
            lines.append(self.collapse)
        if self.last_model_check:
            lines.append(self.last_model_check)
        return "\n".join(lines)


def agent_episodes(agent, wrapper_env, episodes: int, seed: int) -> list:
    """`episodes` episodes of `agent` acting as it explores (SB3 predict(deterministic=False)) in
    `wrapper_env` (a reward wrapper of the model it learns from), episode e reset with seed
    seed + e: a list of (states (L + 1, d), actions (L, A)[, privileged (L + 1, p)]) of the raw
    states (`label_rollouts`)."""
    d = wrapper_env.unwrapped.observation_space.shape[0]
    out = []
    for e in range(episodes):
        obs, info = wrapper_env.reset(seed=seed + e)
        states, actions, privileged, done = [obs[:d].copy()], [], [info.get("privileged")], False
        while not done:
            action = agent.predict(obs, deterministic=False)[0]
            obs, _, terminated, truncated, info = wrapper_env.step(action)
            states.append(obs[:d].copy())
            actions.append(np.asarray(action, np.float32).reshape(-1))
            privileged.append(info.get("privileged"))
            done = terminated or truncated
        episode = (np.stack(states), np.stack(actions))
        out.append(episode if privileged[0] is None else (*episode, np.stack(privileged).astype(np.float32)))
    return out


class LoopRounds(EpisodeCurveCallback):
    """An `EpisodeCurveCallback` that runs `next_round(k)` after the agent's episode
    `boundaries[k - 1]` and swaps the model it returns in (at the start of the next episode, before
    the agent acts on it)."""

    def __init__(self, boundaries: list, next_round, catch_up_steps: int = 0, log=None) -> None:
        super().__init__()
        self.boundaries = list(boundaries)
        self.next_round = next_round
        self.catch_up_steps = int(catch_up_steps)
        self.log = log
        self.round = 0
        self._pending = False

    def _on_step(self) -> bool:
        go_on = super()._on_step()
        if self.round < len(self.boundaries) and len(self.curve.records) >= self.boundaries[self.round]:
            self._pending = True  # swap at the next rollout start: the final transition is stored then
        return go_on

    def _on_rollout_start(self) -> None:
        super()._on_rollout_start()
        if not self._pending or self._stop_next:
            return
        self._pending = False
        self.round += 1
        from .replay_relabel import adopt_model

        model = self.next_round(self.round, self.model)
        if self.keeper is not None:  # a policy is kept with the model it acted on
            self.keeper.retag(str(model), self.model)
        wrapper = find_reward_wrapper(self.training_env.envs[0])
        obs = wrapper.swap_model(model)
        self.model._last_obs = obs[None].copy()  # noqa: SLF001 - the observation the agent acts on next
        t0 = time.perf_counter()
        n, steps = adopt_model(self.model, wrapper.stepper, wrapper.unwrapped.observation_space.shape[0],
                               self.catch_up_steps)
        if self.log is not None:
            self.log(f"agent: {n} stored transitions relabelled with model {self.round}, "
                     f"{steps} catch-up gradient steps ({time.perf_counter() - t0:.0f} s)")


def find_reward_wrapper(env):
    """The `RewardModelWrapper` inside `env` (e.g. under SB3's Monitor)."""
    from .wrappers import RewardModelWrapper

    while not isinstance(env, RewardModelWrapper):
        if not hasattr(env, "env"):
            raise ValueError("the agent's env has no RewardModelWrapper")
        env = env.env
    return env


def round_pairs(n_old: int, n_new: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 2) pairs of episode indices for a round that added episodes [n_old, n_old + n_new)
    to n_old earlier ones: new episode n_old + i % n_new against one drawn uniformly from all the
    others (either may be shown first). With n_old = 0: distinct pairs of the new episodes."""
    from ..datasets.preference_teacher import draw_pairs

    if n_old == 0:
        return draw_pairs(n_new, count, int(rng.integers(2**31)))
    total = n_old + n_new
    a = n_old + np.arange(count) % n_new
    b = rng.integers(0, total - 1, size=count)
    b = b + (b >= a)  # anyone but a itself
    swap = rng.random(count) < 0.5
    return np.column_stack([np.where(swap, b, a), np.where(swap, a, b)]).astype(np.int64)


def last_model_check(learnt: np.ndarray, judged: np.ndarray, model: int, val_return_mse: float,
                     first_returns: np.ndarray):
    """The `model_check.AgentEpisodesCheck` of the loop's last model (model `model`, validation
    return MSE `val_return_mse`) on the agent's episodes it served (learnt, judged: their returns,
    (n,), in order; the last 50 are used); the oracle's scale is at least round 0's labelled
    returns' (first_returns) mean |return| and standard deviation."""
    from .model_check import agent_episodes_check

    first = np.asarray(first_returns, float)
    return agent_episodes_check(learnt, judged, f"last model (model {model})",
                                float(np.sqrt(max(val_return_mse, 0.0))),
                                max(float(np.abs(first).mean()), float(first.std())))


def last_model_verdict(check, rounds: int = 0) -> str:
    """The loop's line for its last model's check: on a FAIL, what it means and what to do."""
    if check.passed:
        return check.summary()
    more = f" (--rounds {rounds + 1})" if rounds else ""
    return (check.summary("the model is still wrong where the agent goes")
            + ". The kept policy was chosen by the oracle's returns too, but do not train new agents on this "
              f"model: more rounds label where it is wrong{more}")


def check_loop_arguments(rounds: int, labels_per_round: int, episodes: int | None,
                         feedback: str = "returns") -> None:
    """ValueError (one line) for a loop that cannot run."""
    from ..feedback import FEEDBACK  # the kinds of feedback training knows

    if feedback not in FEEDBACK:
        raise ValueError(f"feedback must be one of {', '.join(FEEDBACK)}, got {feedback!r}")
    if rounds < 1:
        raise ValueError(f"rounds must be at least 1, got {rounds}")
    if labels_per_round < 10:
        raise ValueError(f"labels per round must be at least 10 (a fifth validates the model), got {labels_per_round}")
    if episodes is not None and episodes < rounds:
        raise ValueError(f"{episodes} agent episodes cannot be split over {rounds} rounds")


def run_loop(task: str, rounds: int, labels_per_round: int, episodes: int | None = None, seed: int = 0,
             out: str | Path = "runs/loop", oracle: str = "", architecture: str = "csc_lstm",
             members: int | None = None, max_epochs: int | None = None, progress: bool = False,
             log=print, feedback: str = "returns", teacher=None) -> LoopResult:
    """Run the loop (module docstring) and write its files to `out`.

    episodes: the agent's training episodes (default config/rl.yaml's); seed: the agent's and
    the episodes' seed, the data seed of round 0 and the models' weight seed; oracle: a user's
    oracle function that labels and judges (default the task's); members, max_epochs: of each
    model (default the task's training config, config/mil_training.yaml); feedback: returns |
    preferences | both; teacher: the `SimulatedTeacher` that compares (default: a perfect one).
    """
    from ..datasets import generate_screened
    from ..datasets.preference_teacher import SimulatedTeacher
    from ..datasets.return_screening import label_rollouts
    from ..datasets.trajectories import concatenate
    from ..mil.retrain import retrain
    from ..mil.training import load_train_config
    from ..oracles import make_oracle
    from .config import algorithm_name, load_rl_config, trust_settings
    from .evaluation import evaluate_agent
    from .training import train_agent
    from .wrappers import make_reward_env

    check_loop_arguments(rounds, labels_per_round, episodes, feedback)
    teacher = (teacher or SimulatedTeacher()).check() if feedback != "returns" else None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cfg = load_train_config(task)
    members = members or cfg.members
    rl_cfg = load_rl_config(algorithm_name(task), task=task, episodes=episodes)
    episodes = int(rl_cfg["episodes"])
    check_loop_arguments(rounds, labels_per_round, episodes)
    judge = make_oracle(task, oracle)
    result = LoopResult(task, out=str(out), feedback=feedback)
    labels = []
    comparisons = []  # each round's answered comparisons (m, 3), indexed into the concatenated episodes

    def train_model(k: int, part, source: str) -> str:
        start = time.perf_counter()
        labels.append(part)
        ds = concatenate(labels)
        asked = len(part)
        if teacher is not None:
            pairs = round_pairs(len(ds) - len(part), len(part), labels_per_round,
                                np.random.default_rng([seed, k, 0x100F]))
            comparisons.append(teacher.answer(ds, pairs, seed + k))
            ds.preferences = np.concatenate(comparisons)
            ds.meta["preferences"] = {"teacher": teacher.to_dict(), "seed": seed}
            asked = len(comparisons[-1])
        ds.save(out / "labels.npz")
        init = str(out / f"model_{k - 1}") if k else None
        summary = retrain(ds, out / f"model_{k}", architecture, members, max_epochs, seed=seed, init=init,
                          bootstrap=False, feedback=feedback)
        total = len(ds.preferences) if feedback == "preferences" else len(ds)
        rnd = Round(k, asked, total, source, summary["checkpoint"], summary,
                    label_mean_return=float(np.mean(part.returns)), seconds=time.perf_counter() - start)
        result.rounds.append(rnd)
        what = f"{asked} labels" if teacher is None else f"{asked} comparisons of {len(part)} episodes"
        score = (f"validation preference accuracy {summary['val_preference_accuracy']:.4f}"
                 if feedback == "preferences" else f"validation return MSE {summary['val_return_mse']:.4f}")
        log(f"round {k}: {what} from {source} (mean return {rnd.label_mean_return:.3f}), "
            f"model {k} on {total}: {score} "
            f"({summary['epochs_run']} epochs, {summary['start'].split(':')[0]}, serving member "
            f"{summary['serving_member']}, {summary['seconds']:.0f} s)")
        write()
        return summary["checkpoint"]

    def next_round(k: int, agent):
        env = make_reward_env(task, "model", result.rounds[-1].checkpoint, seed=seed, oracle=oracle)
        pool = agent_episodes(agent, env, labels_per_round, seed + LABEL_SEED_OFFSET + k * labels_per_round)
        part = label_rollouts(task, judge, pool, {"source": f"agent episodes, round {k}"})
        like = labels[0].actions
        if like is not None and like.ndim == 2:  # discrete actions stored as (n, L) ids, as round 0's
            part.actions = part.actions[..., 0].astype(like.dtype)
        return train_model(k, part, "agent episodes")

    def write() -> None:
        (out / "loop.json").write_text(json.dumps({**asdict(result), "labels_per_round": labels_per_round,
                                                   "rounds_planned": rounds, "episodes": episodes,
                                                   "seed": seed, "oracle": oracle,
                                                   "architecture": architecture, "members": members,
                                                   "teacher": teacher.to_dict() if teacher else None},
                                                  indent=1, default=str))

    first = generate_screened(task, labels_per_round, seed=seed, oracle=oracle)
    checkpoint = train_model(0, first, "screened random episodes")
    boundaries = [round(episodes * k / rounds) for k in range(1, rounds)]
    callback = LoopRounds(boundaries, next_round, trust_settings(rl_cfg)["catch_up_steps"], log)
    run = train_agent(task, "model", checkpoint=checkpoint, episodes=episodes, seed=seed, out=out / "agent",
                      progress=progress, oracle=oracle, callback=callback)
    edges = [0] + boundaries + [episodes]
    returns = np.array([r.oracle_return for r in run.curve.records])
    for k, rnd in enumerate(result.rounds):
        rnd.first_episode, rnd.last_episode = edges[k], edges[k + 1]
        rnd.mean_oracle_return = float(returns[edges[k]:edges[k + 1]].mean()) if edges[k + 1] > edges[k] else float("nan")
    result.final_oracle_return = run.curve.final_oracle_return()
    # the kept policy (kept_policy: the best snapshot of the run), served by the model it acted on
    kept = run.kept_checkpoint or result.rounds[-1].checkpoint
    result.kept_checkpoint, result.collapse = str(kept), run.collapse.summary() if run.collapse else ""
    result.collapsed = bool(run.collapse and run.collapse.collapsed)
    last = result.rounds[-1]
    learnt = np.array([r.learnt_return for r in run.curve.records])[last.first_episode:last.last_episode]
    if feedback != "preferences" and len(learnt) and np.isfinite(last.training.get("val_return_mse", np.nan)):
        check = last_model_check(learnt, returns[last.first_episode:last.last_episode], last.index,
                                 float(last.training["val_return_mse"]), labels[0].returns)
        result.last_model_check, result.last_model_agrees = last_model_verdict(check, rounds), check.passed
    ev = evaluate_agent(run.model, task, kept, reward="model", oracle=oracle)
    result.greedy_oracle_return = float(np.mean(ev.returns))
    result.seconds = time.perf_counter() - t0
    write()
    return result
