"""Label-noise study (paper Sec. 5.2, Fig. 7): return and reward test MSE of the CSC Instance Space
LSTM, the Instance Space LSTM and the Instance Space NN as a fraction p of the training (and
validation) labels is swapped between trajectories.

    .venv/bin/python bench/noise_study.py                                   # the paper's grid
    .venv/bin/python bench/noise_study.py --tasks key --max-epochs 40 --out bench/results/noise_key
    .venv/bin/python bench/noise_study.py --tasks timer --jobs 2 --out bench/results/noise_study_timer
    .venv/bin/python bench/noise_study.py --from-json a.json b.json --out all   # one table and plot

For each (task, architecture), every (p, repeat) pair is one member of a single ensemble trained in
one pass (nmrm_ros.mil.train_ensemble with per-member swap fractions): member (p, r) has weight
seed r and split r (80/10/10 of one screened dataset, data seed 0), so across p only the labels
differ. Test splits are clean. (task, architecture) ensembles go to --jobs worker processes.
Writes OUT.json, OUT.txt (table, and the paper's check: the smallest p at which the CSC model is as
bad as the noise-free Instance Space NN) and OUT.png. --from-json trains nothing: it merges earlier
OUT.json files (e.g. one per task) into one table and one plot.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from nmrm_ros.datasets.cache import cached_dataset

ARCHS = ("csc_lstm", "instance_lstm", "instance_nn")
NAMES = {"csc_lstm": "CSC Instance Space LSTM", "instance_lstm": "Instance Space LSTM",
         "instance_nn": "Instance Space NN"}


def run(task: str, arch: str, levels: list, repeats: int, max_epochs: int | None, threads: int) -> list:
    """Train one (task, architecture) ensemble of every (p, repeat); one row per member."""
    import torch

    from nmrm_ros.mil import evaluate, load_train_config
    from nmrm_ros.mil.data import split_indices
    from nmrm_ros.mil.ensemble import init_ensemble
    from nmrm_ros.mil.training import train_ensemble

    torch.set_num_threads(threads)
    ds = cached_dataset(task, 5000, 0)
    cfg = load_train_config(task, threads=threads, max_epochs=max_epochs)
    members = [(p, r) for p in levels for r in range(repeats)]
    splits = [split_indices(len(ds), r) for _, r in members]
    seeds = [r for _, r in members]
    ens = init_ensemble(cfg.model_config(arch, task, ds.state_size), seeds)
    start = time.perf_counter()
    result = train_ensemble(ens, ds, [(tr, va) for tr, va, _ in splits], cfg, seeds=seeds,
                            progress=False, label_swap=[p for p, _ in members])
    seconds = time.perf_counter() - start
    rows = []
    for m, ((p, r), (_, _, test)) in enumerate(zip(members, splits)):
        metrics = evaluate(ens.member(m), ds.subset(test))
        rows.append({"task": task, "arch": arch, "p": p, "repeat": r, "return_mse": metrics["return_mse"],
                     "reward_mse": metrics["reward_mse"], "best_epoch": result.best_epochs[m],
                     "still_improving": result.still_improving[m], "epochs": result.epochs_run,
                     "seconds": seconds})
    print(f"  {task} {arch}: {len(members)} members, {result.epochs_run} epochs, {seconds:.0f} s", flush=True)
    return rows


def summarise(rows: list, tasks: list, levels: list) -> str:
    lines = []
    for metric in ("return_mse", "reward_mse"):
        lines.append(f"\n{metric} (test, clean labels): mean over repeats [worst]; columns p")
        lines.append(f"{'task':8s} {'model':24s} " + " ".join(f"{p:>16.1f}" for p in levels))
        for task in tasks:
            for arch in ARCHS:
                cells = []
                for p in levels:
                    v = [x[metric] for x in rows if x["task"] == task and x["arch"] == arch and x["p"] == p]
                    cells.append(f"{np.mean(v):8.4f} [{max(v):6.3f}]" if v else " " * 16)
                lines.append(f"{task:8s} {NAMES[arch]:24s} " + " ".join(cells))
    lines.append("\nthe paper's check: smallest p at which the CSC model's mean is as bad as the noise-free "
                 "Instance Space NN's (paper: at least 0.3, except Timer reward)")
    for task in tasks:
        for metric in ("return_mse", "reward_mse"):
            base = [x[metric] for x in rows if x["task"] == task and x["arch"] == "instance_nn" and x["p"] == 0]
            csc = {p: np.mean([x[metric] for x in rows if x["task"] == task and x["arch"] == "csc_lstm"
                               and x["p"] == p]) for p in levels}
            if not base or not all(np.isfinite(list(csc.values()))):
                continue
            worse = [p for p in levels if csc[p] >= np.mean(base)]
            lines.append(f"  {task:8s} {metric:10s}: Instance NN at p=0 {np.mean(base):.4f}; CSC reaches it at "
                         f"p = {worse[0] if worse else f'> {levels[-1]}'}")
    lines.append("\nruns still improving at their epoch limit (best epoch in the last patience epochs)")
    for task in tasks:
        for arch in ARCHS:
            mine = [x for x in rows if x["task"] == task and x["arch"] == arch]
            if mine:
                lines.append(f"  {task:8s} {NAMES[arch]:24s}: {sum(x['still_improving'] for x in mine)} of "
                             f"{len(mine)} ({mine[0]['epochs']} epochs)")
    return "\n".join(lines)


def plot(rows: list, tasks: list, levels: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(tasks), figsize=(3.6 * len(tasks), 6.4), squeeze=False)
    for j, task in enumerate(tasks):
        for i, metric in enumerate(("return_mse", "reward_mse")):
            ax = axes[i, j]
            for arch in ARCHS:
                vals = [[x[metric] for x in rows if x["task"] == task and x["arch"] == arch and x["p"] == p]
                        for p in levels]
                if not all(vals):
                    continue
                mean = np.array([np.mean(v) for v in vals])
                sem = np.array([np.std(v, ddof=1) / np.sqrt(len(v)) if len(v) > 1 else 0 for v in vals])
                ax.errorbar(levels, mean, yerr=sem, marker="o", ms=3, capsize=2, label=NAMES[arch])
            ax.set_yscale("log")
            ax.set_title(f"{task}: {'return' if i == 0 else 'reward'} MSE", fontsize=9)
            ax.set_xlabel("fraction of labels swapped")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=["timer", "moving", "key", "charger"])
    parser.add_argument("--archs", nargs="*", default=list(ARCHS))
    parser.add_argument("--levels", nargs="*", type=float, default=[0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-epochs", type=int, default=None, help="override each task's max_epochs")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("bench/results/noise_study"))
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, one (task, architecture) each")
    parser.add_argument("--from-json", type=Path, nargs="*", default=None, metavar="FILE",
                        help="train nothing: one table and plot of the rows in these OUT.json files")
    args = parser.parse_args()
    start = time.perf_counter()
    if args.from_json:
        rows = merge_rows(args.from_json)
        tasks = [t for t in ("timer", "moving", "key", "charger") if any(x["task"] == t for x in rows)]
        levels = sorted({x["p"] for x in rows})
        epochs = {t: sorted({x["epochs"] for x in rows if x["task"] == t}) for t in tasks}
        text = summarise(rows, tasks, levels) + (f"\n\n# rows of {', '.join(map(str, args.from_json))}; "
                                                 f"epochs run per task {epochs}")
    else:
        print(f"# label-noise study: tasks {args.tasks}, archs {args.archs}, p {args.levels}, "
              f"{args.repeats} repeats, max epochs {args.max_epochs or 'per task config'}, "
              f"{args.jobs} workers x {args.threads} threads", flush=True)
        tasks, levels = args.tasks, args.levels
        jobs = [(task, arch) for task in tasks for arch in args.archs]
        rows = []
        with ProcessPoolExecutor(args.jobs) as pool:
            futures = [pool.submit(run, task, arch, levels, args.repeats, args.max_epochs, args.threads)
                       for task, arch in jobs]
            for future in futures:
                rows += future.result()
                args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
        text = summarise(rows, tasks, levels) + f"\n\n# wall time {time.perf_counter() - start:.0f} s"
    print(text)
    args.out.with_suffix(".txt").write_text(text + "\n")
    plot(rows, tasks, levels, args.out.with_suffix(".png"))


def merge_rows(paths: list) -> list:
    """The rows of several OUT.json files; refused if a (task, architecture, p, repeat) repeats."""
    rows, seen = [], {}
    for path in paths:
        for row in json.loads(Path(path).read_text()):
            key = (row["task"], row["arch"], row["p"], row["repeat"])
            if key in seen:
                raise SystemExit(f"{path}: {key} is also in {seen[key]}")
            seen[key] = path
            rows.append(row)
    return rows

if __name__ == "__main__":
    main()
