"""Reproduce the paper's Figure 4 (Sec. 4.2, App. E): DQN agents on the four 2D navigation tasks,
trained on the CSC Instance Space LSTM's rewards and hidden states, against the oracle with its
hidden state, the oracle without it, and the Markovian Instance Space NN.

    .venv/bin/python bench/reproduce_rl.py --seeds 0 1 2 3 4    # 5 runs per cell, 4 navigation tasks
    .venv/bin/python bench/reproduce_rl.py --tasks lunar_lander --kinds model oracle oracle-no-hidden --seeds 0 1 2
    .venv/bin/python bench/reproduce_rl.py --seeds 0 --tasks key --episodes 100   # a quick look

Run r pairs MIL repeat r with agent seed r, as the paper does. MIL repeat r is the task's default
model (config/mil_training.yaml: Timer, Moving, Key and Charger the mean of 3 models) trained as
bench/any_dataset.py's repeat r: on split r of a screened dataset of data seed r (5000 episodes),
member j with weight seed r + 1000 j; the Markovian Instance Space NN is trained alike. Models are
cached under --work/models; a cached model whose recorded training settings differ from today's
config is trained again, and an agent whose model changed since it learnt (agent.json's
checkpoint_sha256) learns again: the figure is always of today's defaults. Agent r is trained with seed r (SB3 seed; episode e of the env is
seeded r + e, as env_sim's) and served what the model's config says (served_state). Every agent is
judged by the oracle (post hoc). Hyperparameters: config/rl.yaml. Medians and interquartile
ranges over runs are plotted (as the paper's Figure 4), mean ± SEM [worst] tabulated. Episodes: the
algorithm's config (400 for DQN on the navigation tasks, 800 for SAC on Lunar Lander) unless
--episodes. Lunar Lander's curves are also drawn per reward component (pad, no contact, hover,
shaping; the paper's Figure 10): reproduce_rl_lunar_lander_components.png.

Output (bench/results/): reproduce_rl.png (oracle-return curves, median and interquartile range
over runs of a moving average of 20 episodes) and reproduce_rl.txt (final oracle return = mean of the last 50
episodes, mean +/- SEM and worst seed; then the kept policy of each run, policy.zip, greedy on 50 new
episodes as `nmrm rl evaluate` runs it: what a user gets, where Figure 4's number is the training
episodes' at epsilon 0.05), and every run's curve.csv + agent.json + greedy.json, copied to
bench/results/reproduce_rl/agents/ (copy them into --work/agents to continue an incomplete table).
Lunar Lander's models (~90 KB each; an agent on one costs ~1 h, and a new model means a new agent)
are kept in bench/results/reproduce_rl/models/ (copy them into --work/models likewise).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import csv
import hashlib
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from nmrm_ros.mil.checkpoint import recorded_weights_sha256
from nmrm_ros.datasets.cache import stale_data
from nmrm_ros.resume import stale_rl_settings, stale_settings
from nmrm_ros.tasks import NAVIGATION_TASKS

TASKS = NAVIGATION_TASKS
ALL_TASKS = TASKS + ("lunar_lander",)
#: reward kind -> (label, MIL architecture or None)
KINDS = {
    "model": ("CSC Instance Space LSTM", "csc_lstm"),
    "oracle": ("Oracle (with hidden state)", None),
    "oracle-no-hidden": ("Oracle (without hidden state)", None),
    "markovian": ("Instance Space NN (Markovian)", "instance_nn"),
}
FINAL_WINDOW = 50
#: the kept policy (policy.zip) is also judged greedy on this many new episodes (`nmrm rl evaluate`)
GREEDY_EPISODES = 50


def model_path(work: Path, task: str, arch: str, seed: int) -> Path:
    return work / "models" / f"{task}_{arch}_seed{seed}"


def train_reward_model(job: tuple) -> dict:
    """Train (or reuse) MIL repeat `seed` of (task, arch); returns its test metrics."""
    work, task, arch, seed = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.datasets.cache import cached_dataset
    from nmrm_ros.mil import DataSource, load_train_config
    from nmrm_ros.mil.pipeline import fit

    out = model_path(work, task, arch, seed)
    meta_file = out.with_suffix(".json")
    cfg = load_train_config(task, seed=seed)
    if meta_file.is_file():
        meta = json.loads(meta_file.read_text())
        stale = stale_settings(meta.get("train_config", {}), cfg) + stale_data(meta.get("data", {}).get("meta"), task)
        if not stale:
            return {"task": task, "arch": arch, "seed": seed, **meta["metrics"]["test"], "cached": True}
        print(f"  {task} {arch} seed {seed}: trained with other settings or data than today's "
              f"({', '.join(stale)}): training again", flush=True)
    ds = cached_dataset(task, 5000, seed)
    run = fit(ds, arch, cfg, cfg.members, split_seed=seed, out=out, progress=False,
                             data_source=DataSource.generated(task, 5000, seed),
                             offsets=[1000 * j for j in range(cfg.members)])
    return {"task": task, "arch": arch, "seed": seed, **run.test_metrics,
            "seconds": run.train.seconds, "cached": False}


def train_agent_job(job: tuple) -> dict:
    work, task, kind, seed, episodes = job
    episodes = episodes_of(task, episodes)
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl import train_agent

    arch = KINDS[kind][1]
    reward = "model" if arch else kind
    checkpoint = model_path(work, task, arch, seed) if arch else None
    out = work / "agents" / f"{task}_{kind}_seed{seed}"
    if (out / "curve.csv").is_file() and len(read_curve(out / "curve.csv")) == episodes \
            and learnt_on(out, checkpoint) and not stale_agent(out, task, episodes):
        return {"task": task, "kind": kind, "seed": seed, "out": str(out), "cached": True,
                "greedy": kept_greedy(out, task)}
    t0 = time.perf_counter()
    train_agent(task, reward, checkpoint=checkpoint, episodes=episodes, seed=seed, out=out,
                progress=False)
    return {"task": task, "kind": kind, "seed": seed, "out": str(out), "cached": False,
            "seconds": time.perf_counter() - t0, "greedy": kept_greedy(out, task)}


def kept_greedy(out: Path, task: str) -> float | None:
    """Mean oracle return of the agent's kept policy (out/policy.zip: what a user gets) run greedy
    on GREEDY_EPISODES new episodes (`nmrm rl evaluate`: episode seeds from 10^8, the reward model
    of its agent.json); cached in out/greedy.json for that policy file (its SHA-256). None without
    a policy."""
    policy = out / "policy.zip"
    if not policy.is_file():
        return None
    sha = hashlib.sha256(policy.read_bytes()).hexdigest()
    cache = out / "greedy.json"
    if cache.is_file():
        recorded = json.loads(cache.read_text())
        if recorded.get("policy_sha256") == sha and recorded.get("episodes") == GREEDY_EPISODES:
            return float(recorded["oracle_return"])
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl import evaluate_agent

    result = evaluate_agent(policy, task, episodes=GREEDY_EPISODES)
    value = float(np.mean(result.returns))
    cache.write_text(json.dumps({"policy_sha256": sha, "episodes": GREEDY_EPISODES, "oracle_return": value,
                                 "random_policy": float(np.mean(result.random_returns))}, indent=1) + "\n")
    return value


def greedy_job(job: tuple) -> float | None:
    return kept_greedy(*job)


def stale_agent(out: Path, task: str, episodes: int) -> list[str]:
    """How the finished agent in `out` was trained with other RL settings than today's (config/rl.yaml
    for `task`; empty: it stands)."""
    recorded = json.loads((out / "agent.json").read_text()).get("config") if (out / "agent.json").is_file() else None
    stale = stale_rl_settings(recorded, task, episodes=episodes)
    if stale:
        print(f"# {out.name}: not today's RL settings ({'; '.join(stale)}): training again", flush=True)
    return stale


def learnt_on(out: Path, checkpoint: Path | None) -> bool:
    """Whether the finished agent in `out` learnt on the reward model now at `checkpoint` (its
    agent.json's checkpoint_sha256; agents from before that field: trained after the model was)."""
    if checkpoint is None:
        return True
    model_meta = checkpoint.with_suffix(".json")
    if not model_meta.is_file():
        return False
    recorded = json.loads((out / "agent.json").read_text()).get("checkpoint_sha256") \
        if (out / "agent.json").is_file() else None
    if recorded is not None:
        return recorded == recorded_weights_sha256(checkpoint)
    return (out / "curve.csv").stat().st_mtime > model_meta.stat().st_mtime


def episodes_of(task: str, episodes: int | None) -> int:
    """`episodes`, else the task's algorithm's config (config/rl.yaml)."""
    from nmrm_ros.rl import algorithm_name, load_rl_config

    return int(episodes or load_rl_config(algorithm_name(task), task=task)["episodes"])


def read_curve(path: Path) -> list:
    with open(path) as f:
        return list(csv.DictReader(f))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=list(TASKS), choices=list(ALL_TASKS))
    parser.add_argument("--kinds", nargs="*", default=list(KINDS), choices=list(KINDS))
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--episodes", type=int, default=None, help="default: config/rl.yaml's (400 DQN, 800 SAC)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--work", type=Path, default=Path("runs/reproduce_rl"),
                        help="models/ and agents/ (a run whose agents/NAME/curve.csv exists is not run "
                             "again: copy bench/results/reproduce_rl/agents there to continue a table, and "
                             "bench/results/reproduce_rl/models, Lunar Lander's models, whose agents cost ~1 h)")
    parser.add_argument("--models-only", action="store_true", help="train the reward models and stop")
    parser.add_argument("--results", type=Path, default=Path("bench/results"))
    parser.add_argument("--report-only", action="store_true", help="only tabulate and plot the runs done so far")
    args = parser.parse_args()
    start = time.perf_counter()
    if args.report_only:
        report(args, 0.0)
        return

    model_jobs = [(args.work, t, KINDS[k][1], s) for s in args.seeds for t in args.tasks
                  for k in args.kinds if KINDS[k][1]]
    print(f"# {len(model_jobs)} reward models, {args.jobs} workers", flush=True)
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(train_reward_model, model_jobs):
            print(f"  {r['task']:8s} {r['arch']:12s} seed {r['seed']}: test return MSE {r['return_mse']:.4f}, "
                  f"reward MSE {r['reward_mse']:.5f}{' (cached)' if r['cached'] else ''}", flush=True)
    if args.models_only:
        return
    agent_jobs = [(args.work, t, k, s, args.episodes) for s in args.seeds for t in args.tasks for k in args.kinds]
    print(f"# {len(agent_jobs)} agents, {args.jobs} workers", flush=True)
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(train_agent_job, agent_jobs):
            curve = read_curve(Path(r["out"]) / "curve.csv")
            final = np.mean([float(row["oracle_return"]) for row in curve[-FINAL_WINDOW:]])
            took = "cached" if r["cached"] else f"{r['seconds']:.0f} s"
            greedy = "" if r["greedy"] is None else f", kept policy greedy {r['greedy']:7.2f}"
            print(f"  {r['task']:8s} {r['kind']:17s} seed {r['seed']}: final oracle return {final:7.2f}{greedy} ({took})",
                  flush=True)
    report(args, time.perf_counter() - start)


def report(args, seconds: float) -> None:
    """The table and plots of every run in --work (all five tasks, four kinds and seeds that have
    runs, whatever this invocation trained)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args.results.mkdir(parents=True, exist_ok=True)
    # every run done, whatever seeds this invocation trained (a `--seeds 0` run redraws the whole figure)
    args.seeds = sorted({int(p.parent.name.rsplit("_seed", 1)[1]) for p in (args.work / "agents").glob("*_seed*/curve.csv")}
                        | set(args.seeds))
    ran = lambda t, k: any((args.work / "agents" / f"{t}_{k}_seed{s}" / "curve.csv").is_file()  # noqa: E731
                           for s in args.seeds)
    args.tasks = [t for t in ALL_TASKS if any(ran(t, k) for k in KINDS)] or args.tasks
    args.kinds = [k for k in KINDS if any(ran(t, k) for t in args.tasks)] or args.kinds
    fig, axes = plt.subplots(1, len(args.tasks), figsize=(4.2 * len(args.tasks), 3.4), squeeze=False)
    episodes = ", ".join(f"{t} {episodes_of(t, args.episodes)}" for t in args.tasks)
    lines = [f"# Figure 4: final oracle return (mean of the last {FINAL_WINDOW} episodes of {episodes}) "
             f"over the runs done (n) of seeds {args.seeds}: median [interquartile range]; mean ± SEM [worst]",
             f"# command: .venv/bin/python bench/reproduce_rl.py --tasks {' '.join(args.tasks)} "
             f"--kinds {' '.join(args.kinds)} --seeds {' '.join(map(str, args.seeds))}"
             + (f" --episodes {args.episodes}" if args.episodes else ""),
             f"{'task':8s} {'reward':32s} {'n':>2s} {'median [IQR]':>24s} {'mean ± SEM [worst]':>26s}  per run"]
    finals = {}
    for i, task in enumerate(args.tasks):
        ax = axes[0][i]
        for kind in args.kinds:
            curves, seeds = [], []
            for seed in args.seeds:
                path = args.work / "agents" / f"{task}_{kind}_seed{seed}" / "curve.csv"
                if path.is_file():
                    curves.append([float(r["oracle_return"]) for r in read_curve(path)])
                    seeds.append(seed)
            if not curves:
                continue
            n = min(len(c) for c in curves)
            arr = np.array([c[:n] for c in curves])
            finals[(task, kind)] = (arr[:, -FINAL_WINDOW:].mean(axis=1), seeds)
            smooth = np.array([np.convolve(c, np.ones(20) / 20, mode="valid") for c in arr])
            q25, med, q75 = np.percentile(smooth, [25, 50, 75], axis=0)
            x = np.arange(len(med)) + 20
            ax.plot(x, med, label=KINDS[kind][0])
            ax.fill_between(x, q25, q75, alpha=0.25)
        ax.set_title(task.replace("_", " ").title())
        ax.set_xlabel("episode")
        if i == 0:
            ax.set_ylabel("oracle return (median, IQR)")
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    png = args.results / "reproduce_rl.png"
    fig.savefig(png, dpi=120)
    if "lunar_lander" in args.tasks:
        plot_components(args)
    for task in args.tasks:
        for kind in args.kinds:
            if (task, kind) not in finals:
                continue
            v, seeds = finals[(task, kind)]
            q25, med, q75 = np.percentile(v, [25, 50, 75])
            sem = v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else 0.0
            runs = ", ".join(f"{s}: {x:.1f}" for s, x in zip(seeds, v))
            lines.append(f"{task:8s} {KINDS[kind][0]:32s} {len(v):2d} {med:7.2f} [{q25:6.2f}, {q75:6.2f}] "
                         f"{v.mean():7.2f} ± {sem:5.2f} [{v.min():6.2f}]  {runs}")
    greedy_jobs = [(args.work / "agents" / f"{t}_{k}_seed{s}", t) for t in args.tasks for k in args.kinds
                   for s in finals.get((t, k), ((), []))[1]]
    with ProcessPoolExecutor(args.jobs) as pool:  # evaluated once per policy (greedy.json), then read
        greedy = dict(zip([(str(o), t) for o, t in greedy_jobs], pool.map(greedy_job, greedy_jobs)))
    lines.append(f"# the kept policy (policy.zip, what a user gets) greedy on {GREEDY_EPISODES} new episodes "
                 f"(`nmrm rl evaluate`, seeds from 10^8): median [worst]; per run")
    greedy_medians = {}
    for task in args.tasks:
        for kind in args.kinds:
            if (task, kind) not in finals:
                continue
            seeds = finals[(task, kind)][1]
            values = [(s, greedy[(str(args.work / "agents" / f"{task}_{kind}_seed{s}"), task)]) for s in seeds]
            known = np.array([v for _, v in values if v is not None])
            if not known.size:
                continue
            greedy_medians[(task, kind)] = float(np.median(known))
            runs = ", ".join(f"{s}: {'-' if v is None else f'{v:.1f}'}" for s, v in values)
            lines.append(f"{task:8s} {KINDS[kind][0]:32s} {len(known):2d} {np.median(known):7.2f} [{known.min():6.2f}]  {runs}")
    if ("model" in args.kinds and "oracle" in args.kinds) and greedy_medians:
        lines.append("# kept policies greedy, median CSC / median oracle-with-hidden: " + ", ".join(
            f"{t} {greedy_medians[(t, 'model')] / greedy_medians[(t, 'oracle')]:.0%}" for t in args.tasks
            if (t, "model") in greedy_medians and greedy_medians.get((t, "oracle"), 0) > 0))
    if "model" in args.kinds and "oracle" in args.kinds:
        ratios = []
        for task in args.tasks:
            if (task, "model") in finals and (task, "oracle") in finals:
                o = np.median(finals[(task, "oracle")][0])
                ratios.append(f"{task} {np.median(finals[(task, 'model')][0]) / o:.0%}" if o > 0 else f"{task} n/a")
        lines.append("# median CSC / median oracle-with-hidden final return: " + ", ".join(ratios))
    if seconds:
        lines.append(f"# wall time {seconds:.0f} s on {os.cpu_count()} cores")
    lines.append(f"# curves: {png}; per run: {args.work}/agents/*/curve.csv")
    text = "\n".join(lines)
    print(text)
    (args.results / "reproduce_rl.txt").write_text(text + "\n")
    kept = args.results / "reproduce_rl" / "agents"   # the curves (not the policies) are kept in git
    for path in sorted((args.work / "agents").glob("*/curve.csv")):
        (kept / path.parent.name).mkdir(parents=True, exist_ok=True)
        for name in ("curve.csv", "agent.json", "greedy.json"):
            if (path.parent / name).is_file():
                (kept / path.parent.name / name).write_bytes((path.parent / name).read_bytes())


def plot_components(args) -> None:
    """Lunar Lander's oracle return per reward component along training (the paper's Figure 10):
    median and interquartile range over runs, a moving average of 20 episodes."""
    import matplotlib.pyplot as plt

    names = ("pad", "no_contact", "hover", "shaping")
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.4), squeeze=False)
    for kind in args.kinds:
        runs = []
        for seed in args.seeds:
            path = args.work / "agents" / f"lunar_lander_{kind}_seed{seed}" / "curve.csv"
            if path.is_file():
                rows = read_curve(path)
                if rows and f"oracle_{names[0]}" in rows[0]:
                    runs.append(np.array([[float(r[f"oracle_{n}"]) for n in names] for r in rows]))
        if not runs:
            continue
        n = min(len(r) for r in runs)
        arr = np.array([r[:n] for r in runs])  # (runs, episodes, components)
        for j, name in enumerate(names):
            smooth = np.array([np.convolve(r[:, j], np.ones(20) / 20, mode="valid") for r in arr])
            q25, med, q75 = np.percentile(smooth, [25, 50, 75], axis=0)
            x = np.arange(len(med)) + 20
            axes[0][j].plot(x, med, label=KINDS[kind][0])
            axes[0][j].fill_between(x, q25, q75, alpha=0.25)
            axes[0][j].set_title(f"Lunar Lander: {name}")
            axes[0][j].set_xlabel("episode")
    axes[0][0].set_ylabel("oracle return (median, IQR)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.results / "reproduce_rl_lunar_lander_components.png", dpi=120)


if __name__ == "__main__":
    main()
