"""The reward-model <-> agent loop against one offline dataset with the same label budget.

    .venv/bin/python bench/reward_model_loop.py --tasks key timer --budgets 500 1000 2000 --seeds 0 1 2
    .venv/bin/python bench/reward_model_loop.py --report      # the table and plot of what is there

For each task, label budget B and seed s, two runs of `nmrm loop` (nmrm_ros.rl.reward_model_loop)
with the task's default models (config/mil_training.yaml) and agent (config/rl.yaml, 400
episodes of double DQN), both judged by the oracle:

- loop: --rounds R (default 4) --labels-per-round B / R: round 0 labels B / R screened random
  episodes (data seed s), rounds 1..R-1 label the agent's own episodes;
- offline: --rounds 1 --labels-per-round B: B screened random episodes (data seed s), one model.

Figures: the agent's final oracle return (mean of its last 50 training episodes) and its greedy
policy's oracle return on 50 new episodes; per cell the median and the range over seeds.

`--feedback preferences`: the same with a perfect simulated teacher's comparisons instead of
return labels (B comparisons in all: B / R a round, each new episode against earlier ones; the
offline run: B comparisons of B screened random episodes); results in
bench/results/reward_model_loop/preferences/.

Resumes: each run's loop.json is copied to bench/results/reward_model_loop/[preferences/]<task>_<mode>_<B>_s<s>.json,
and a run whose file exists is not run again.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "reward_model_loop"
MODES = ("loop", "offline")


def run_name(task: str, mode: str, budget: int, seed: int) -> str:
    return f"{task}_{mode}_{budget}_s{seed}"


def results_dir(feedback: str) -> Path:
    return RESULTS if feedback == "returns" else RESULTS / feedback


def run_one(job: tuple) -> dict:
    task, mode, budget, seed, rounds, work, feedback = job
    results = results_dir(feedback)
    done = results / f"{run_name(task, mode, budget, seed)}.json"
    if done.is_file():
        return json.loads(done.read_text())
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl.reward_model_loop import run_loop

    name = run_name(task, mode, budget, seed) + ("" if feedback == "returns" else f"_{feedback}")
    out = work / name
    shutil.rmtree(out, ignore_errors=True)  # an interrupted run starts again
    r = rounds if mode == "loop" else 1
    log = open(work / f"{name}.log", "w")
    run_loop(task, r, budget // r, seed=seed, out=out, log=lambda m: print(m, file=log, flush=True),
             feedback=feedback)
    results.mkdir(parents=True, exist_ok=True)
    shutil.copy(out / "loop.json", done)
    return json.loads(done.read_text())


#: the order tasks are reported in
TASK_ORDER = ("key", "timer", "moving", "charger", "lunar_lander")


def report(feedback: str = "returns") -> str:
    """The table (table.txt) and plot (loop_vs_offline.png) of every run in the results directory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = results_dir(feedback)
    what = "labels" if feedback == "returns" else "comparisons"
    runs = [json.loads(p.read_text()) for p in sorted(results.glob("*.json"))]
    if not runs:
        return f"# no runs in {results} yet"
    present = {r["task"] for r in runs}
    tasks = [t for t in TASK_ORDER if t in present] + sorted(present - set(TASK_ORDER))
    budgets = sorted({sum(x["labels"] for x in r["rounds"]) for r in runs})
    groups: dict = {}  # the tasks run with each set of budgets: one command per set
    for t in tasks:
        key = tuple(sorted({sum(x["labels"] for x in r["rounds"]) for r in runs if r["task"] == t}))
        groups.setdefault(key, []).append(t)
    commands = ["# command: .venv/bin/python bench/reward_model_loop.py --tasks " + " ".join(ts) + " --budgets "
                + " ".join(map(str, bs)) + ("" if feedback == "returns" else f" --feedback {feedback}")
                + f" (loop: 4 rounds of budget / 4 {what}; offline: 1 round)" for bs, ts in groups.items()]
    lines = [f"# bench/reward_model_loop.py ({feedback}): final oracle return (mean of the last 50 of 400 training "
             "episodes) / greedy policy on 50 new episodes; median [min, max] over seeds (n)", *commands,
             f"{'task':8s} {what[:6]:>6s} {'mode':8s} {'n':>2s} {'final':>26s} {'greedy':>26s} {'rounds':>6s}"]
    fig, axes = plt.subplots(1, len(tasks), figsize=(4.5 * len(tasks), 3.4), squeeze=False)
    for i, task in enumerate(tasks):
        ax = axes[0][i]
        cells = {}
        for mode in MODES:
            for b in budgets:
                cell = [r for r in runs if r["task"] == task and sum(x["labels"] for x in r["rounds"]) == b
                        and (len(r["rounds"]) > 1) == (mode == "loop")]
                if cell:
                    cells[(mode, b)] = cell
        for b in budgets:
            for mode in MODES:
                if (mode, b) not in cells:
                    continue
                cell = cells[(mode, b)]
                final = np.array([r["final_oracle_return"] for r in cell])
                greedy = np.array([r["greedy_oracle_return"] for r in cell])
                lines.append(f"{task:8s} {b:6d} {mode:8s} {len(cell):2d} "
                             f"{np.median(final):8.2f} [{final.min():6.2f}, {final.max():6.2f}] "
                             f"{np.median(greedy):8.2f} [{greedy.min():6.2f}, {greedy.max():6.2f}] "
                             f"{len(cell[0]['rounds']):6d}  seeds {[r['seed'] for r in cell]}")
        for mode, colour in zip(MODES, ("tab:blue", "tab:grey")):
            xs = [b for b in budgets if (mode, b) in cells]
            if not xs:
                continue
            greedy = [np.array([r["greedy_oracle_return"] for r in cells[(mode, b)]]) for b in xs]
            ax.plot(xs, [np.median(g) for g in greedy], "o-", color=colour, label=f"{mode} (median, range over seeds)")
            ax.fill_between(xs, [g.min() for g in greedy], [g.max() for g in greedy], color=colour, alpha=0.2)
        ax.set_xscale("log")
        ax.set_xticks(budgets, [str(b) for b in budgets])
        ax.set_xlabel("labels (episodes)" if feedback == "returns" else "comparisons")
        ax.set_title(task.capitalize())
        if i == 0:
            ax.set_ylabel("greedy oracle return")
            ax.legend(fontsize=7)
    fig.tight_layout()
    results.mkdir(parents=True, exist_ok=True)
    fig.savefig(results / "loop_vs_offline.png", dpi=120)
    text = "\n".join(lines)
    (results / "table.txt").write_text(text + "\n")
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=["key", "timer"])
    parser.add_argument("--budgets", nargs="*", type=int, default=[500, 1000, 2000])
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--modes", nargs="*", default=list(MODES), choices=MODES)
    parser.add_argument("--rounds", type=int, default=4, help="rounds of the loop runs")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--work", type=Path, default=Path("runs/reward_model_loop"))
    parser.add_argument("--report", action="store_true", help="run nothing: the table and plot of every run there is (any task, budget)")
    parser.add_argument("--feedback", default="returns", choices=("returns", "preferences"),
                        help="return labels, or a perfect simulated teacher's comparisons")
    args = parser.parse_args()
    if not args.report:
        args.work.mkdir(parents=True, exist_ok=True)
        results = results_dir(args.feedback)
        jobs = [(t, m, b, s, args.rounds, args.work, args.feedback) for s in args.seeds for b in args.budgets
                for t in args.tasks for m in args.modes if not (results / f"{run_name(t, m, b, s)}.json").is_file()]
        print(f"# {len(jobs)} runs (finished ones skipped), {args.jobs} workers", flush=True)
        with ProcessPoolExecutor(args.jobs) as pool:
            for job, r in zip(jobs, pool.map(run_one, jobs)):
                print(f"  {run_name(*job[:4])}: final {r['final_oracle_return']:.2f}, greedy "
                      f"{r['greedy_oracle_return']:.2f}, {r['seconds']:.0f} s", flush=True)
    print(report(args.feedback))


if __name__ == "__main__":
    main()
