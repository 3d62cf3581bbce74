"""Model quality on any dataset: the paper's protocol with a different dataset per repeat.

    .venv/bin/python bench/any_dataset.py --tasks key charger --repeats 10 --jobs 2
    .venv/bin/python bench/any_dataset.py --tasks key --set schedule=cosine max_epochs=100 members=1 --tag key_old

Repeat r trains the task's default model (config/mil_training.yaml, then --set overrides; Timer,
Moving and Key: the mean of 3 models, member j with weight seed r + 1000 j) on split r of a
screened dataset of **data seed r** (5000 episodes), and is scored on its test split and on a
held-out set of 2000 screened episodes of data seed 999 (no repeat trains on it). Each cell: mean
± SEM [worst] over repeats; "over" counts the runs above the paper's bar (mean + 2 SEM) on the
held-out set.

Resumes: each repeat's result is bench/results/any_dataset/<tag>/<task>_r<r>.json, and a repeat
whose file exists is not trained again (delete it to redo it). --report prints the table of what
is there without training.
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

from nmrm_ros.paper import PAPER_RETURN, PAPER_REWARD, mean_sem, mean_seconds
from nmrm_ros.datasets.cache import cached_dataset
from nmrm_ros.mil.training import parse_settings
from nmrm_ros.tasks import NAVIGATION_TASKS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "any_dataset"
NAV = NAVIGATION_TASKS
HELD_OUT_SEED, HELD_OUT_N = 999, 2000


def run_repeat(job: tuple) -> dict:
    """Train and score repeat r of `task`; writes and returns its result (or reads it, when another
    process of the same tag finished it since this one started: sittings may run side by side)."""
    task, r, overrides, out = job
    done = out / f"{task}_r{r}.json"
    if done.is_file():
        return json.loads(done.read_text())
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.mil import evaluate, fit, load_train_config

    ds = cached_dataset(task, 5000, r)
    held = cached_dataset(task, HELD_OUT_N, HELD_OUT_SEED)
    cfg = load_train_config(task, seed=r, **overrides)
    # weight seeds r + 1000 j (cfg.seed = r), split r; seconds: CPU time of fit (the training and its
    # evaluation of each member, a few seconds; as wall time on 1 thread)
    t0 = time.process_time()
    run = fit(ds, "csc_lstm", cfg, members=cfg.members, split_seed=r, offsets=[1000 * j for j in range(cfg.members)],
              progress=False)
    seconds = time.process_time() - t0
    result, seeds, on_test, on_held = run.train, run.meta.ensemble.seeds, run.meta.metrics["test"], evaluate(run.model, held)
    res = {"task": task, "repeat": r, "data_seed": r, "weight_seeds": seeds, "split_seed": r,
           "held_out_seed": HELD_OUT_SEED, "members": len(seeds),
           "test_return_mse": on_test["return_mse"], "test_reward_mse": on_test["reward_mse"],
           "held_return_mse": on_held["return_mse"], "held_reward_mse": on_held["reward_mse"],
           "best_epochs": result.best_epochs, "epochs": result.epochs_run,
           "still_improving": result.still_improving, "seconds": seconds, "clock": "cpu", "config": cfg.to_dict()}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{task}_r{r}.json").write_text(json.dumps(res, indent=1))
    return res


def report(out: Path, tasks: list) -> str:
    lines = [f"# {out.relative_to(ROOT)}: CSC, repeat r on data seed r (weights, split r); held-out: "
             f"{HELD_OUT_N} episodes of data seed {HELD_OUT_SEED}",
             "# mean ± SEM [worst]; over: runs above the paper's bar (mean + 2 SEM) on the held-out set",
             f"{'task':8s} {'n':>3s} {'held-out return':>26s} {'bar':>6s} {'over':>4s} "
             f"{'held-out reward':>30s} {'bar':>7s} {'over':>4s} {'test return':>22s} {'s/run':>6s} {'epochs':>7s}"]
    for task in tasks:
        runs = sorted((json.loads(p.read_text()) for p in out.glob(f"{task}_r*.json")), key=lambda r: r["repeat"])
        if not runs:
            continue
        bar_ret = PAPER_RETURN["csc_lstm"][task][0] + 2 * PAPER_RETURN["csc_lstm"][task][1]
        bar_rew = PAPER_REWARD["csc_lstm"][task][0] + 2 * PAPER_REWARD["csc_lstm"][task][1]
        hr = [r["held_return_mse"] for r in runs]
        hw = [r["held_reward_mse"] for r in runs]
        tr = [r["test_return_mse"] for r in runs]
        m, s = mean_sem(hr)
        mw, sw = mean_sem(hw)
        mt, st = mean_sem(tr)
        over_ret = [r["repeat"] for r in runs if r["held_return_mse"] > bar_ret]
        over_rew = [r["repeat"] for r in runs if r["held_reward_mse"] > bar_rew]
        lines.append(f"{task:8s} {len(runs):3d} {m:8.3f} ± {s:6.3f} [{max(hr):6.3f}] {bar_ret:6.3f} {len(over_ret):4d} "
                     f"{mw:9.5f} ± {sw:8.5f} [{max(hw):8.5f}] {bar_rew:7.4f} {len(over_rew):4d} "
                     f"{mt:7.3f} ± {st:5.3f} [{max(tr):5.3f}] {mean_seconds(runs)} "
                     f"{int(np.median([r['epochs'] for r in runs])):7d}")
        improving = [r["repeat"] for r in runs if any(r["still_improving"])]
        lines.append(f"{'':8s} repeats {[r['repeat'] for r in runs]}; over the return bar {over_ret}, the reward bar "
                     f"{over_rew}; stopped at the epoch limit while improving {improving}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=list(NAV), choices=NAV)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--only", type=int, nargs="*", default=None, help="train only these repeats (of --repeats)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training-config overrides")
    parser.add_argument("--tag", default="head", help="results go to bench/results/any_dataset/TAG/")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--report", action="store_true", help="train nothing: print the table")
    args = parser.parse_args()
    out = RESULTS / args.tag
    if not args.report:
        overrides = parse_settings(args.set)
        jobs = [(t, r, overrides, out) for t in args.tasks for r in range(args.repeats)
                if not (out / f"{t}_r{r}.json").is_file() and (args.only is None or r in args.only)]
        print(f"# {len(jobs)} runs to train (finished ones skipped), overrides {overrides}", flush=True)
        with ProcessPoolExecutor(args.jobs) as pool:
            for res in pool.map(run_repeat, jobs):
                print(f"  {res['task']} repeat {res['repeat']}: held-out return {res['held_return_mse']:.4f} reward "
                      f"{res['held_reward_mse']:.5f}; test return {res['test_return_mse']:.4f} (epochs "
                      f"{res['epochs']}, best {res['best_epochs']}, {res['seconds']:.0f} s)", flush=True)
    text = report(out, list(NAV))
    print(text)
    (out / "table.txt").parent.mkdir(parents=True, exist_ok=True)
    (out / "table.txt").write_text(text + f"\n# command: bench/any_dataset.py --tasks {' '.join(args.tasks)} "
                                   f"--tag {args.tag}{' --set ' + ' '.join(args.set) if args.set else ''}\n")


if __name__ == "__main__":
    main()
