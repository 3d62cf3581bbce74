"""Reproduce the paper's MIL reward-modelling tables: the toy table (App. C.3) and Table 1 (the four
2D navigation tasks), for all four architectures, as mean +/- SEM over repeats beside the paper.

    .venv/bin/python bench/reproduce_tables.py                  # quick: 1 repeat
    .venv/bin/python bench/reproduce_tables.py --repeats 10     # the paper's protocol
    .venv/bin/python bench/reproduce_tables.py --tables nav --tasks key charger --archs csc_lstm

Repeat r trains with weight seed r on split r (80/10/10) of one dataset per task (data seed 0),
as the paper repeated its experiments over ten splits. Hyperparameters: config/mil_training.yaml.
Runs go to --jobs worker processes (one torch thread each).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ARCHS = ("instance_nn", "embedding_lstm", "instance_lstm", "csc_lstm")
TOY = ("toggle_switch", "push_switch", "dial")
NAV = ("timer", "moving", "key", "charger")

# Paper values (mean, SEM): App. C Table "toy results" and Sec. 4 Table 1.
PAPER_RETURN = {
    "instance_nn": {"toggle_switch": (0.030, 0.029), "push_switch": (3.337, 0.054), "dial": (5.489, 0.157),
                    "timer": (130.8, 1.530), "moving": (22.24, 0.441), "key": (7.764, 0.232), "charger": (7.783, 0.214)},
    "embedding_lstm": {"toggle_switch": (0.008, 0.002), "push_switch": (0.663, 0.194), "dial": (0.434, 0.075),
                       "timer": (3.151, 0.662), "moving": (13.04, 0.899), "key": (0.360, 0.055), "charger": (0.689, 0.124)},
    "instance_lstm": {"toggle_switch": (0.062, 0.058), "push_switch": (0.262, 0.154), "dial": (0.111, 0.014),
                      "timer": (7.313, 2.627), "moving": (11.13, 1.169), "key": (0.488, 0.062), "charger": (0.628, 0.126)},
    "csc_lstm": {"toggle_switch": (0.000, 0.000), "push_switch": (0.140, 0.065), "dial": (0.121, 0.043),
                 "timer": (0.605, 0.166), "moving": (5.307, 0.299), "key": (0.391, 0.083), "charger": (0.125, 0.012)},
}
PAPER_REWARD = {
    "instance_nn": {"toggle_switch": (0.002, 0.002), "push_switch": (0.086, 0.001), "dial": (0.954, 0.011),
                    "timer": (0.217, 0.001), "moving": (0.068, 0.000), "key": (0.011, 0.000), "charger": (0.025, 0.000)},
    "embedding_lstm": {"toggle_switch": (0.003, 0.001), "push_switch": (0.206, 0.100), "dial": (0.244, 0.077),
                       "timer": (101.8, 60.35), "moving": (3.033, 0.715), "key": (0.010, 0.008), "charger": (0.037, 0.016)},
    "instance_lstm": {"toggle_switch": (0.004, 0.004), "push_switch": (0.021, 0.008), "dial": (0.026, 0.004),
                      "timer": (0.263, 0.038), "moving": (0.069, 0.005), "key": (0.002, 0.000), "charger": (0.005, 0.001)},
    "csc_lstm": {"toggle_switch": (0.000, 0.000), "push_switch": (0.012, 0.004), "dial": (0.022, 0.007),
                 "timer": (0.073, 0.016), "moving": (0.026, 0.002), "key": (0.001, 0.000), "charger": (0.001, 0.000)},
}


def run_one(job: tuple) -> dict:
    task, arch, repeat, n, max_epochs = job
    from nmrm_ros.datasets import generate_screened, make_toy_dataset
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.pipeline import train_and_evaluate

    ds = make_toy_dataset(task, n, seed=0) if task in TOY else generate_screened(task, n, seed=0)
    cfg = load_train_config(task, seed=repeat, max_epochs=max_epochs)
    run = train_and_evaluate(ds, arch, cfg, split_seed=repeat, progress=False)
    return {"task": task, "arch": arch, "repeat": repeat, "return_mse": run.test_metrics["return_mse"],
            "reward_mse": run.test_metrics["reward_mse"], "seconds": run.train.seconds,
            "epochs": run.train.epochs_run, "best_epoch": run.train.best_epoch}


def mean_sem(values: list) -> tuple:
    v = np.asarray(values, dtype=np.float64)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0


def fmt(ms: tuple) -> str:
    return f"{ms[0]:.3f} ± {ms[1]:.3f}"


def print_table(results: list, tasks: tuple, metric: str, paper: dict, archs: tuple) -> None:
    print(f"\n{metric} (test MSE; ours | paper)")
    print(f"{'model':16s} " + " ".join(f"{t:>34s}" for t in tasks))
    for arch in archs:
        cells = []
        for task in tasks:
            vals = [r[metric] for r in results if r["task"] == task and r["arch"] == arch]
            ours = fmt(mean_sem(vals)) if vals else "-"
            cells.append(f"{ours:>16s} | {fmt(paper[arch][task]):>15s}")
        print(f"{arch:16s} " + " ".join(f"{c:>34s}" for c in cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--tables", nargs="*", default=["toy", "nav"], choices=["toy", "nav"])
    parser.add_argument("--tasks", nargs="*", default=None, help="subset of tasks")
    parser.add_argument("--archs", nargs="*", default=list(ARCHS))
    parser.add_argument("--n", type=int, default=5000, help="bags per dataset (paper: 5000)")
    parser.add_argument("--max-epochs", type=int, default=None, help="override (for a smoke run)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--json", type=Path, default=None, help="also write all runs here")
    args = parser.parse_args()
    tasks = tuple(t for table in args.tables for t in (TOY if table == "toy" else NAV))
    if args.tasks:
        tasks = tuple(t for t in tasks if t in args.tasks)
    jobs = [(t, a, r, args.n, args.max_epochs) for r in range(args.repeats) for t in tasks for a in args.archs]
    print(f"# {len(jobs)} runs: tasks {tasks}, archs {args.archs}, repeats (seeds/splits) "
          f"0..{args.repeats - 1}, data seed 0, {args.jobs} workers", flush=True)
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for res in pool.map(run_one, jobs):
            results.append(res)
            print(f"  {res['task']:13s} {res['arch']:15s} seed {res['repeat']}: return {res['return_mse']:.4f} "
                  f"reward {res['reward_mse']:.5f} ({res['epochs']} epochs, best {res['best_epoch']}, "
                  f"{res['seconds']:.0f} s)", flush=True)
    for group in (TOY, NAV):
        sel = tuple(t for t in tasks if t in group)
        if sel:
            print_table(results, sel, "return_mse", PAPER_RETURN, tuple(args.archs))
            print_table(results, sel, "reward_mse", PAPER_REWARD, tuple(args.archs))
    print(f"\n# wall time {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
