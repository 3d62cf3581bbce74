"""Reward models from preferences: held-out preference accuracy and learnt-vs-true reward
correlation against the number of comparisons, CSC vs the Instance Space NN, perfect and noisy
simulated teachers (and return labels for reference).

    .venv/bin/python bench/preferences.py --tasks key timer charger --jobs 2
    .venv/bin/python bench/preferences.py --tasks key --pairs 1000 --archs csc_lstm --teachers perfect --seeds 0
    .venv/bin/python bench/preferences.py --report

Run (task, arch, teacher, n, seed r): the screened dataset of data seed r (5000 episodes, the
any-dataset protocol), split r (80/10/10); teacher `perfect` (B-Pref's oracle: beta = inf) or
`noisy` (beta = 1, mistake 0.1) compares n uniformly drawn pairs (seed r; a comparison with a
test episode is never trained on), and the task's default model (config/mil_training.yaml,
weight seeds r + 1000 j) trains on them with the Bradley–Terry loss (`--feedback preferences`);
teacher `returns` trains on the return labels of n episodes (a seeded subset) instead, for
reference. Scored on 2000 held-out screened episodes of data seed 999: preference accuracy over
all pairs with different true returns, and Pearson's r of the predicted and the oracle's per-step
rewards. Each cell: mean [worst] over seeds.

RL (`--rl`; `--rl --report` only redraws rl.txt from the agents kept): double DQN through the wrapper (config/rl.yaml, 400 episodes, agent seed r) on the
CSC models of (perfect, 4000 comparisons) and of (returns, 4000 labels), seed r each, judged by
the oracle: final oracle return = mean of the last 50 episodes. The models are the runs above
(their checkpoints are kept in runs/preferences/<tag>/models/; a run without one is trained again).
A third agent learns on the model of comparisons calibrated to return units (`nmrm calibrate`:
nmrm_ros.mil.calibration) with CAL_LABELS return labels of its own training data (a subset of seed r).

Resumes: each run is bench/results/preferences/<tag>/<task>_<arch>_<teacher>_n<n>_s<r>.json, each
agent's curve bench/results/preferences/<tag>/agents/<name>/curve.csv; what exists is not run again.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from nmrm_ros.paper import mean_seconds
from nmrm_ros.datasets.cache import cached_dataset
from nmrm_ros.datasets.preference_teacher import TEACHERS as NAMED_TEACHERS
from nmrm_ros.mil.training import parse_settings

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "preferences"
TASKS = ("key", "timer", "charger", "moving")
ARCHS = ("csc_lstm", "instance_nn")
TEACHERS = {**NAMED_TEACHERS, "returns": None}  # returns: n return labels instead of comparisons
PAIRS = (250, 500, 1000, 2000, 4000)
HELD_OUT_SEED, HELD_OUT_N = 999, 2000
MODELS = ROOT / "runs" / "preferences"  # checkpoints of the runs (not in git)
RL_N, FINAL_WINDOW = 4000, 50
CAL_LABELS = 50  # return labels that calibrate the model of comparisons for the third agent
RL_TEACHERS = ("returns", "perfect", "calibrated")


def run_name(task: str, arch: str, teacher: str, n: int, r: int) -> str:
    return f"{task}_{arch}_{teacher}_n{n}_s{r}"


def training_data(task: str, teacher: str, n: int, r: int):
    """(dataset, feedback) of run (task, teacher, n, r): n comparisons of the teacher, or n
    return-labelled episodes."""
    from nmrm_ros.datasets.preference_teacher import SimulatedTeacher, with_preferences

    ds = cached_dataset(task, 5000, r)
    if TEACHERS[teacher] is None:
        pick = np.sort(np.random.default_rng([r, 0x51]).permutation(len(ds))[:n])
        return ds.subset(pick), "returns"
    return with_preferences(ds, n, SimulatedTeacher(**TEACHERS[teacher]), seed=r), "preferences"


def run(job: tuple) -> dict:
    """Train and score one run; writes and returns its result."""
    task, arch, teacher, n, r, overrides, out = job
    done = out / f"{run_name(task, arch, teacher, n, r)}.json"
    if done.is_file() and (MODELS / out.name / "models" / f"{done.stem}.pt").is_file():
        return json.loads(done.read_text())  # finished meanwhile, by another process (--rl needs the model too)
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.mil import evaluate, fit, load_train_config

    ds, feedback = training_data(task, teacher, n, r)
    held = cached_dataset(task, HELD_OUT_N, HELD_OUT_SEED)
    cfg = load_train_config(task, seed=r, feedback=feedback, **overrides)
    # weight seeds r + 1000 j (cfg.seed = r), split r; seconds: CPU time of fit (the training and its
    # evaluation of each member, a few seconds; as wall time on 1 thread)
    t0 = time.process_time()
    run = fit(ds, arch, cfg, members=cfg.members, split_seed=r, offsets=[1000 * j for j in range(cfg.members)],
              progress=False)
    seconds = time.process_time() - t0
    result, seeds, on_test, on_held = run.train, run.meta.ensemble.seeds, run.meta.metrics["test"], evaluate(run.model, held)
    keep = ("preference_accuracy", "reward_correlation", "reward_correlation_centred", "return_mse", "reward_mse")
    res = {"task": task, "arch": arch, "teacher": teacher, "teacher_knobs": TEACHERS[teacher], "n": n,
           "seed": r, "data_seed": r, "weight_seeds": seeds, "feedback": feedback,
           "comparisons": 0 if ds.preferences is None else len(ds.preferences),
           "test": {k: on_test[k] for k in keep}, "held": {k: on_held[k] for k in keep},
           "best_epochs": result.best_epochs, "epochs": result.epochs_run,
           "still_improving": result.still_improving, "seconds": seconds, "clock": "cpu", "config": cfg.to_dict()}
    run.replace(metrics={**run.meta.metrics, "held": on_held}).save(
        MODELS / out.name / "models" / run_name(task, arch, teacher, n, r))
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{run_name(task, arch, teacher, n, r)}.json").write_text(json.dumps(res, indent=1))
    return res


def agent(job: tuple) -> dict:
    """Train (or reuse) the agent on the model of run (task, csc_lstm, teacher, RL_N, r)."""
    task, teacher, r, overrides, out, episodes = job
    import csv

    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl import train_agent

    source = "perfect" if teacher == "calibrated" else teacher  # the run whose model the agent's is
    base = run_name(task, "csc_lstm", source, RL_N, r)
    name = base + (f"_cal{CAL_LABELS}" if teacher == "calibrated" else "")
    checkpoint = MODELS / out.name / "models" / f"{name}.pt"
    agent_dir = out / "agents" / name
    curve = agent_dir / "curve.csv"
    if not curve.is_file():
        if not (MODELS / out.name / "models" / f"{base}.pt").is_file():
            run((task, "csc_lstm", source, RL_N, r, overrides, out))
        if teacher == "calibrated" and not checkpoint.is_file():
            calibrated_model(MODELS / out.name / "models" / base, checkpoint, task, r)
        t0 = time.perf_counter()
        train_agent(task, "model", checkpoint=checkpoint, episodes=episodes, seed=r,
                    out=MODELS / out.name / "agents" / name, progress=False)
        agent_dir.mkdir(parents=True, exist_ok=True)
        for f in ("curve.csv", "agent.json"):
            (agent_dir / f).write_bytes((MODELS / out.name / "agents" / name / f).read_bytes())
        seconds = time.perf_counter() - t0
    else:
        seconds = float("nan")
    with open(curve) as f:
        returns = [float(row["oracle_return"]) for row in csv.DictReader(f)]
    return {"task": task, "teacher": teacher, "seed": r, "final": float(np.mean(returns[-FINAL_WINDOW:])),
            "episodes": len(returns), "seconds": seconds}


def calibrated_model(src: Path, dst: Path, task: str, r: int) -> None:
    """Write the model `src` calibrated on CAL_LABELS return labels of its training data (seed r)."""
    from nmrm_ros.mil import DataSource, Run
    from nmrm_ros.mil.calibration import calibrate, fit_calibration

    run = Run.load(src, task=task)
    ds = cached_dataset(task, 5000, r)
    pick = np.sort(np.random.default_rng([r, 0xCA1]).choice(len(ds), CAL_LABELS, replace=False))
    fit = fit_calibration(run.model, ds.subset(pick))
    run.replace(model=calibrate(run.model, fit), calibration={
        **fit.to_dict(), "from": str(src), "data": str(DataSource.generated(task, 5000, r))}).save(dst)


def kept_agents(out: Path) -> list:
    """Every agent kept in out/agents whose name is a --rl run (task, returns|perfect, seed), as agent()
    returns it: the table covers all seeds measured so far, whichever sitting ran them."""
    import csv
    import re

    found = []
    for curve in sorted((out / "agents").glob("*/curve.csv")):
        m = re.fullmatch(rf"(\w+?)_csc_lstm_(returns|perfect)_n{RL_N}_s(\d+)(_cal{CAL_LABELS})?", curve.parent.name)
        if not m:
            continue
        with open(curve) as f:
            returns = [float(row["oracle_return"]) for row in csv.DictReader(f)]
        found.append({"task": m[1], "teacher": "calibrated" if m[4] else m[2], "seed": int(m[3]),
                      "final": float(np.mean(returns[-FINAL_WINDOW:])), "episodes": len(returns)})
    return found


def rl_report(out: Path, results: list) -> str:
    lines = [f"# {out.relative_to(ROOT)}/agents: double DQN through the wrapper (config/rl.yaml) on the CSC model "
             f"trained from {RL_N} comparisons of a perfect teacher vs from {RL_N} return labels; final oracle "
             f"return = mean of the last {FINAL_WINDOW} episodes; mean [worst] over seeds (ratio: of the means); "
             f"calibrated: the model of comparisons calibrated on {CAL_LABELS} return labels (`nmrm calibrate`)",
             f"{'task':8s} {'from returns':>18s} {'from comparisons':>18s} {'ratio':>6s} {'calibrated':>18s} "
             f"{'ratio':>6s} seeds"]

    def mean_worst(values: list) -> str:
        return f"{np.mean(values):8.2f} [{min(values):6.2f}]" if values else f"{'–':>18s}"

    def ratio(values: list, reference: list) -> str:
        return f"{np.mean(values) / np.mean(reference):6.0%}" if values and np.mean(reference) > 0 else f"{'–':>6s}"

    for task in TASKS:
        cell = {k: [x["final"] for x in results if x["task"] == task and x["teacher"] == k] for k in RL_TEACHERS}
        if not cell["returns"] or not cell["perfect"]:
            continue
        seeds = sorted({x["seed"] for x in results if x["task"] == task})
        lines.append(f"{task:8s} {mean_worst(cell['returns'])} {mean_worst(cell['perfect'])} "
                     f"{ratio(cell['perfect'], cell['returns'])} {mean_worst(cell['calibrated'])} "
                     f"{ratio(cell['calibrated'], cell['returns'])} {seeds}")
    return "\n".join(lines)


def _cell(runs: list, key: str, worst=min) -> str:
    values = [r["held"].get(key, float("nan")) for r in runs]
    if not values or any(v != v for v in values):
        return f"{'–':>15s}"
    return f"{np.mean(values):6.3f} [{worst(values):6.3f}]"


def report(out: Path) -> str:
    runs = [json.loads(p.read_text()) for p in sorted(out.glob("*_s*.json"))]
    lines = [f"# {out.relative_to(ROOT)}: held-out ({HELD_OUT_N} episodes of data seed {HELD_OUT_SEED}) "
             "preference accuracy (all pairs with different true returns) and reward correlation "
             "(Pearson r, per step; centred: after removing each step index's mean over the episodes, "
             "the part comparisons can identify); mean [worst] over seeds; teacher perfect: beta = inf; "
             "noisy: beta = 1, mistake 0.1; returns: n return labels instead of n comparisons; s/run: "
             "training CPU seconds (w: wall seconds of runs from before, pauses of the bench included)",
             f"{'task':8s} {'arch':12s} {'teacher':8s} {'n':>5s} {'seeds':>5s} {'pref. accuracy':>15s} "
             f"{'reward corr.':>15s} {'centred corr.':>15s} {'s/run':>6s}"]
    key = lambda r: (TASKS.index(r["task"]), ARCHS.index(r["arch"]), list(TEACHERS).index(r["teacher"]), r["n"])
    groups: dict = {}
    for r in sorted(runs, key=key):
        groups.setdefault(key(r), []).append(r)
    for cell in groups.values():
        r0 = cell[0]
        lines.append(f"{r0['task']:8s} {r0['arch']:12s} {r0['teacher']:8s} {r0['n']:5d} "
                     f"{','.join(str(r['seed']) for r in cell):>5s} {_cell(cell, 'preference_accuracy')} "
                     f"{_cell(cell, 'reward_correlation')} {_cell(cell, 'reward_correlation_centred')} "
                     f"{mean_seconds(cell)}")
    return "\n".join(lines)


def plot(out: Path) -> Path | None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [json.loads(p.read_text()) for p in sorted(out.glob("*_s*.json"))]
    tasks = [t for t in TASKS if any(r["task"] == t for r in runs)]
    if not tasks:
        return None
    fig, axes = plt.subplots(2, len(tasks), figsize=(4.2 * len(tasks), 6.5), squeeze=False)  # rows: accuracy, centred corr.
    styles = {("csc_lstm", "perfect"): ("C0", "-"), ("csc_lstm", "noisy"): ("C0", "--"),
              ("instance_nn", "perfect"): ("C3", "-"), ("instance_nn", "noisy"): ("C3", "--"),
              ("csc_lstm", "returns"): ("0.4", ":"), ("instance_nn", "returns"): ("C1", ":")}
    for col, task in enumerate(tasks):
        for row, metric in enumerate(("preference_accuracy", "reward_correlation_centred")):
            ax = axes[row, col]
            for (arch, teacher), (colour, line) in styles.items():
                cell = [r for r in runs if (r["task"], r["arch"], r["teacher"]) == (task, arch, teacher)]
                ns = sorted({r["n"] for r in cell})
                if not ns:
                    continue
                worst = [min(r["held"].get(metric, np.nan) for r in cell if r["n"] == n) for n in ns]
                mean = [np.mean([r["held"].get(metric, np.nan) for r in cell if r["n"] == n]) for n in ns]
                ax.plot(ns, worst, line, color=colour, marker="o", label=f"{arch}, {teacher} (worst seed)")
                ax.plot(ns, mean, line, color=colour, alpha=0.35)
            ax.set_xscale("log")
            ax.set_xticks(PAIRS, [str(n) for n in PAIRS])
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_title(f"{task}: {metric.replace('_', ' ')}")
            ax.set_xlabel("comparisons (returns: labels)")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    path = out / "preferences.png"
    fig.savefig(path, dpi=110)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=["key", "timer", "charger"], choices=TASKS)
    parser.add_argument("--archs", nargs="*", default=list(ARCHS), choices=ARCHS)
    parser.add_argument("--teachers", nargs="*", default=["perfect", "noisy"], choices=list(TEACHERS))
    parser.add_argument("--pairs", nargs="*", type=int, default=list(PAIRS), help="comparisons (or labels)")
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training-config overrides")
    parser.add_argument("--tag", default="head", help="results go to bench/results/preferences/TAG/")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--report", action="store_true", help="train nothing: print the table and plot")
    parser.add_argument("--rl", action="store_true", help="train agents on the models of 4000 comparisons "
                                                         "(as trained, and calibrated on 50 return labels) and of "
                                                         "4000 return labels (see above)")
    parser.add_argument("--episodes", type=int, default=400, help="--rl: episodes per agent")
    args = parser.parse_args()
    out = RESULTS / args.tag
    if args.rl:
        overrides = parse_settings(args.set)
        jobs = [(t, k, r, overrides, out, args.episodes) for r in args.seeds for t in args.tasks
                for k in RL_TEACHERS]
        print(f"# {len(jobs)} agents (finished ones reused)" if not args.report else "# the agents kept so far",
              flush=True)
        if not args.report:
            with ProcessPoolExecutor(args.jobs) as pool:
                list(pool.map(agent, jobs))
        kept = kept_agents(out)
        text = rl_report(out, kept)
        print(text)
        seeds = " ".join(map(str, sorted({x["seed"] for x in kept})))
        tasks = " ".join(t for t in TASKS if any(x["task"] == t for x in kept))  # the table's tasks, not --tasks
        (out / "rl.txt").write_text(text + f"\n# command: .venv/bin/python bench/preferences.py --rl --tasks "
                                    f"{tasks} --seeds {seeds} --episodes {args.episodes} (a task's "
                                    f"row: the seeds it has so far; `--rl --report` redraws)\n")
        return
    if not args.report:
        overrides = parse_settings(args.set)
        # the cheapest first: a sitting cut short leaves the small cells complete
        jobs = sorted(((t, a, k, n, r, overrides, out) for t in args.tasks for a in args.archs
                       for k in args.teachers for n in args.pairs for r in args.seeds
                       if not (out / f"{run_name(t, a, k, n, r)}.json").is_file()),
                      key=lambda j: (j[3], j[4], j[0], j[1], j[2]))
        print(f"# {len(jobs)} runs to train (finished ones skipped), overrides {overrides}", flush=True)
        with ProcessPoolExecutor(args.jobs) as pool:
            for res in pool.map(run, jobs):
                h = res["held"]
                print(f"  {run_name(res['task'], res['arch'], res['teacher'], res['n'], res['seed'])}: held-out "
                      f"preference accuracy {h['preference_accuracy']:.3f}, reward correlation "
                      f"{h['reward_correlation']:.3f} ({res['epochs']} epochs, {res['seconds']:.0f} s)", flush=True)
    text = report(out)
    print(text)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.txt").write_text(text + f"\n# command: bench/preferences.py --tag {args.tag} (runs: one "
                                   f"JSON each in this directory){' --set ' + ' '.join(args.set) if args.set else ''}\n")
    png = plot(out)
    if png:
        print(f"# plot: {png.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
