"""Reproduce the paper's MIL reward-modelling tables: the toy table (App. C.3) and Table 1 (the four
2D navigation tasks and Lunar Lander), for all four architectures, as mean +/- SEM over repeats
beside the paper.

    .venv/bin/python bench/reproduce_tables.py                  # quick: 1 repeat
    .venv/bin/python bench/reproduce_tables.py --repeats 10     # the paper's protocol
    .venv/bin/python bench/reproduce_tables.py --tables nav --tasks key charger --archs csc_lstm
    .venv/bin/python bench/reproduce_tables.py --tasks timer --archs csc_lstm --set lr=1e-3
    .venv/bin/python bench/reproduce_tables.py --tables ll --repeats 4 --archs csc_lstm
    .venv/bin/python bench/reproduce_tables.py --tasks moving --archs csc_lstm --seeds 1 3 --json a.json
    .venv/bin/python bench/reproduce_tables.py --from-json a.json b.json   # one table of both runs

Lunar Lander (App. D.4): MSEs in the paper's scaled units (returns / 100; reward MSE shown x 1e5),
over all repeats and over the best half by reward MSE (the paper's "top 5 of 10").

Repeat r trains with weight seed r on split r (80/10/10) of one dataset per task (data seed
--data-seed, default 0), as the paper repeated its experiments over ten splits. The repeats of one
(task, architecture) are trained as one ensemble in one pass (nmrm_ros.mil.train_ensemble: each
member exactly its own run, on its own split). Hyperparameters: config/mil_training.yaml, then
--set overrides. (task, architecture) jobs go to --jobs worker processes (--threads torch
threads each). Datasets are cached in runs/data/. Each cell shows mean +/- SEM, the worst run, and
the paper's mean +/- SEM; "bar" is the paper's mean + 2 SEM.
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

from nmrm_ros.datasets.cache import cached_dataset
from nmrm_ros.mil.training import parse_settings
from nmrm_ros.paper import PAPER_RETURN, PAPER_REWARD, mean_sem
from nmrm_ros.mil import ARCHITECTURES
from nmrm_ros.tasks import NAVIGATION_TASKS

ARCHS = ARCHITECTURES  # the paper's four, in its order
TOY = ("toggle_switch", "push_switch", "dial")
NAV = NAVIGATION_TASKS
LL = ("lunar_lander",)
TABLES = {"toy": TOY, "nav": NAV, "ll": LL}
LL_REWARD_UNIT = 1e-5  # the paper's Lunar Lander reward MSEs are given in units of 1e-5

def epoch_logger(label: str, every: int):
    """on_epoch callback printing the members' validation return MSE every `every` epochs."""
    def log(entry: dict) -> bool:
        if every and entry["epoch"] % every == 0:
            v = np.asarray(entry["val_return_mse"])
            print(f"    [{label}] epoch {entry['epoch']} ({entry['seconds']:.0f} s, lr {entry['lr']:.2g}): "
                  f"val return MSE median {np.median(v):.3f}, worst {v.max():.3f}", flush=True)
        return False

    return log


def run_ensemble(job: tuple) -> list:
    """Train the repeats of one (task, architecture) as one ensemble; one dict per repeat."""
    task, arch, repeats, n, data_seed, overrides, threads, log_every, save, members, member0_from = job
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.pipeline import fit

    ds = cached_dataset(task, n, data_seed)
    # the repeats are independent runs (the paper's protocol), not an ensemble: every one is kept
    cfg = load_train_config(task, seed=0, threads=threads, **{"keep_members": "all", **overrides})
    members = cfg.members if members is None else members
    if members > 1:
        return run_repeat_ensembles(task, arch, repeats, members, ds, cfg, log_every, save, data_seed,
                                    member0_from)

    run = fit(ds, arch, cfg, members=len(repeats), split_seed=0,
                             split_mode="per_member", progress=False,
                             on_epoch=epoch_logger(f"{task} {arch}", log_every),
                             offsets=list(repeats),
                             out=None if save is None else Path(save) / f"{task}_{arch}")
    return [{"task": task, "arch": arch, "repeat": r, "data_seed": data_seed, "n": len(ds),
             **table_metrics(task, run.member_test[m]),
             "seconds": run.train.seconds, "epochs": run.train.epochs_run,
             "best_epoch": run.train.best_epochs[m], "still_improving": run.train.still_improving[m],
             "config": cfg.to_dict()} for m, r in enumerate(repeats)]


def saved_members0(path: Path, task: str, arch: str, repeats: list, cfg, n: int, data_seed: int) -> dict:
    """Member 0 of each repeat from a one-model `--save` run: {repeat: (model, best_epoch,
    still_improving, that run's training seconds)}. Refused unless that run trained repeat r with weight seed r on split r
    of the same dataset, with the same settings: then its model is exactly what member 0 would be
    (each member of a batched ensemble is its own run; checked on Timer)."""
    from nmrm_ros.mil import load_checkpoint

    ckpt = Path(path) / f"{task}_{arch}"
    saved, meta = load_checkpoint(ckpt)
    ens = meta.ensemble
    if ens.split_mode != "per_member" or ens.seeds != ens.split_seeds:
        raise SystemExit(f"{ckpt}: not a one-model-per-repeat run (reproduce_tables --members 1 --save)")
    if meta.data.n != n or meta.data.meta.get("seed") != data_seed:
        raise SystemExit(f"{ckpt}: trained on {meta.data.n} bags of data seed "
                         f"{meta.data.meta.get('seed')}, not {n} of data seed {data_seed}")
    ignore = ("seed", "threads", "members")
    theirs = {k: v for k, v in with_defaults(meta.train_config).items() if k not in ignore}
    ours = {k: v for k, v in cfg.to_dict().items() if k not in ignore}
    if theirs != ours:
        diff = sorted(k for k in set(theirs) | set(ours) if theirs.get(k) != ours.get(k))
        raise SystemExit(f"{ckpt}: trained with other settings ({', '.join(diff)} differ)")
    missing = [r for r in repeats if r not in ens.seeds]
    if missing:
        raise SystemExit(f"{ckpt}: has no run of repeat(s) {missing}")
    m = meta.metrics
    return {r: (saved.member(i), m["best_epochs"][i], m["still_improving"][i], m["seconds"])
            for i, r in enumerate(ens.seeds) if r in repeats}


def run_repeat_ensembles(task, arch, repeats, members, ds, cfg, log_every, save, data_seed,
                         member0_from=None) -> list:
    """Repeat r is an ensemble of `members` models on split r (member j: weight seed r + 1000 j,
    so member 0 is the single-model run of repeat r), scored on its mean prediction; all the
    repeats' members train in one pass. With `member0_from` (a one-model `--save` run of the same
    settings) member 0 is loaded from there and only members 1.. are trained. One dict per repeat:
    the ensemble's metrics, and member 0's as `single_*`."""
    from nmrm_ros.mil import evaluate
    from nmrm_ros.mil.data import split_indices
    from nmrm_ros.mil.ensemble import MILEnsemble, init_ensemble
    from nmrm_ros.mil.training import train_ensemble

    reused = {} if member0_from is None else saved_members0(member0_from, task, arch, repeats, cfg,
                                                            len(ds), data_seed)
    layout = [(r, j) for r in repeats for j in range(1 if reused else 0, members)]
    seeds = [r + 1000 * j for r, j in layout]
    splits = {r: split_indices(len(ds), r) for r in repeats}
    config = cfg.model_config(arch, ds.task, ds.state_size)
    ens = init_ensemble(config, seeds)

    result = train_ensemble(ens, ds, [splits[r][:2] for r, _ in layout], cfg, seeds=seeds,
                            progress=False, on_epoch=epoch_logger(f"{task} {arch} x{members}", log_every))
    if save is not None:
        from nmrm_ros.mil import DataSource, Run
        from nmrm_ros.mil.checkpoint import DataInfo, EnsembleInfo

        Run.of(ens, ds.task, seed=seeds[0], split_seed=repeats[0], train_config=cfg.to_dict(),
               data=DataInfo(DataSource.generated(task, len(ds), data_seed), len(ds), ds.meta),
               ensemble=EnsembleInfo(len(seeds), 0, seeds, [r for r, _ in layout], "per_member")
               ).save(Path(save) / f"{task}_{arch}_x{members}")
    runs = []
    for r in repeats:
        idx = [i for i, (rr, _) in enumerate(layout) if rr == r]
        models = [ens.member(i) for i in idx]
        best = [result.best_epochs[i] for i in idx]
        improving = [result.still_improving[i] for i in idx]
        member_seeds = [seeds[i] for i in idx]
        seconds0 = None
        if reused:
            model0, best0, improving0, seconds0 = reused[r]
            models, best, improving = [model0, *models], [best0, *best], [improving0, *improving]
            member_seeds = [r, *member_seeds]
        test = ds.subset(splits[r][2])
        mean_metrics = table_metrics(task, evaluate(MILEnsemble.from_members(models), test))
        single = table_metrics(task, evaluate(models[0], test))
        runs.append({"task": task, "arch": arch, "repeat": r, "data_seed": data_seed, "n": len(ds),
                     "members": members, "member_seeds": member_seeds, **mean_metrics,
                     **{f"single_{k}": v for k, v in single.items()},
                     "seconds": result.seconds, "epochs": result.epochs_run,
                     "best_epoch": max(best), "still_improving": any(improving),
                     "member0_from": None if member0_from is None else str(member0_from),
                     "member0_seconds": seconds0,  # the reused run's own training time (not in `seconds`)
                     "config": cfg.to_dict()})
    return runs


def table_metrics(task: str, test: dict) -> dict:
    """The test MSEs in the paper's table units: label units, except Lunar Lander (returns / 100,
    reward MSE in units of 1e-5); label-unit values kept beside."""
    if task not in LL:
        return {"return_mse": test["return_mse"], "reward_mse": test["reward_mse"],
                "reward_mse_time_profile": test["reward_mse_time_profile"]}
    return {"return_mse": test["return_mse_scaled"], "reward_mse": test["reward_mse_scaled"] / LL_REWARD_UNIT,
            "reward_mse_time_profile": test["reward_mse_time_profile_scaled"] / LL_REWARD_UNIT,
            "return_mse_label_units": test["return_mse"], "reward_mse_label_units": test["reward_mse"]}


def best_half(results: list) -> list:
    """The paper's Lunar Lander protocol: per (task, architecture), the best half of the repeats
    by reward MSE (its "top 5 of 10")."""
    keep = []
    for key in sorted({(r["task"], r["arch"]) for r in results}):
        rs = sorted((r for r in results if (r["task"], r["arch"]) == key), key=lambda r: r["reward_mse"])
        keep.extend(rs[: max(1, len(rs) // 2)])
    return keep


def fmt(ms: tuple) -> str:
    return f"{ms[0]:.3f} ± {ms[1]:.3f}"


def fmt_value(v: float) -> str:
    return f"{v:.4f}" if v < 10 else f"{v:.1f}"


def print_table(results: list, tasks: tuple, metric: str, paper: dict, archs: tuple) -> None:
    print(f"\n{metric} (test MSE; ours: mean ± SEM, worst | paper: mean ± SEM)")
    print(f"{'model':16s} " + " ".join(f"{t:>44s}" for t in tasks))
    for arch in archs:
        cells = []
        for task in tasks:
            vals = [r[metric] for r in results if r["task"] == task and r["arch"] == arch]
            ours = f"{fmt(mean_sem(vals))}, {fmt_value(max(vals))}" if vals else "-"
            cells.append(f"{ours:>26s} | {fmt(paper[arch][task]):>15s}")
        print(f"{arch:16s} " + " ".join(f"{c:>44s}" for c in cells))


def print_bar_check(results: list, tasks: tuple, archs: tuple) -> None:
    """Runs over the paper's mean + 2 SEM, per cell, and runs still improving at the epoch limit."""
    print("\nruns over the bar (paper mean + 2 SEM) on return | reward MSE; still improving at the limit")
    for arch in archs:
        for task in tasks:
            rs = [r for r in results if r["task"] == task and r["arch"] == arch]
            if not rs:
                continue
            bar_ret = PAPER_RETURN[arch][task][0] + 2 * PAPER_RETURN[arch][task][1]
            bar_rew = PAPER_REWARD[arch][task][0] + 2 * PAPER_REWARD[arch][task][1]
            over_ret = [r["repeat"] for r in rs if r["return_mse"] > bar_ret]
            over_rew = [r["repeat"] for r in rs if r["reward_mse"] > bar_rew]
            improving = [r["repeat"] for r in rs if r.get("still_improving")]
            print(f"  {arch:15s} {task:13s} bar {bar_ret:.3f} | {bar_rew:.4f}: over {len(over_ret)}/{len(rs)} "
                  f"{over_ret} | {len(over_rew)}/{len(rs)} {over_rew}; still improving {improving}")


def report(results: list, tasks: tuple, archs: tuple) -> None:
    """Print the tables, the bar check and (Lunar Lander) the best half, for `results`."""
    for group in (TOY, NAV):
        sel = tuple(t for t in tasks if t in group)
        if sel:
            print_table(results, sel, "return_mse", PAPER_RETURN, archs)
            print_table(results, sel, "reward_mse", PAPER_REWARD, archs)
            print_bar_check(results, sel, archs)
    if "lunar_lander" in tasks:
        print("\nLunar Lander, all repeats (returns / 100; reward MSE x 1e5)", end="")
        print_table(results, LL, "return_mse", PAPER_RETURN, archs)
        print_table(results, LL, "reward_mse", PAPER_REWARD, archs)
        best = best_half(results)
        print("\nLunar Lander, the best half by reward MSE (the paper's protocol: top 5 of 10): repeats "
              + ", ".join(f"{r['arch']} {r['repeat']}" for r in best), end="")
        print_table(best, LL, "return_mse", PAPER_RETURN, archs)
        print_table(best, LL, "reward_mse", PAPER_REWARD, archs)
        print_bar_check(results, LL, archs)


def report_all(results: list, tasks: tuple, archs: tuple) -> None:
    """`report`; where repeats were ensembles (--members), first of their means, then of each
    repeat's member 0 alone."""
    if not any(r.get("members", 1) > 1 for r in results):
        report(results, tasks, archs)
        return
    print("\n# each repeat: the mean of its members (--members):", end="")
    report(results, tasks, archs)
    singles = [dict(r, **{k[len("single_"):]: v for k, v in r.items() if k.startswith("single_")})
               for r in results]
    print("\n# member 0 of each repeat alone (the one-model run of that repeat):", end="")
    report(singles, tasks, archs)


def with_defaults(config: dict) -> dict:
    """A saved training config with the settings added since it was saved at their defaults (the
    value those runs had: a setting is added with a default that keeps the old behaviour)."""
    from nmrm_ros.mil.training import TrainConfig

    return dict(TrainConfig().to_dict(), **config)


def merge_runs(paths: list) -> list:
    """The runs of several --json files as one table (e.g. repeats 1, 3, 8, 9 and 0, 2, 4-7):
    refused if a (task, architecture, repeat) appears twice or the training configs differ."""
    results, seen, configs = [], set(), {}
    for path in paths:
        for run in json.loads(Path(path).read_text()):
            key = (run["task"], run["arch"], run["repeat"])
            if key in seen:
                raise SystemExit(f"{path}: {key} is in an earlier file too")
            seen.add(key)
            config = {k: v for k, v in with_defaults(run["config"]).items() if k not in ("seed", "threads")}
            first = configs.setdefault(key[:2], (path, config))
            if first[1] != config:
                raise SystemExit(f"{path}: {key[:2]} was trained with other settings than in {first[0]}")
            results.append(run)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=1, help="repeats 0..N-1 (repeat r: weight seed r, split r)")
    parser.add_argument("--seeds", type=int, nargs="*", default=None,
                        help="only these repeats (e.g. rerun a table's failing runs exactly); overrides --repeats")
    parser.add_argument("--tables", nargs="*", default=["toy", "nav"], choices=list(TABLES),
                        help="toy, nav (Timer, Moving, Key, Charger), ll (Lunar Lander; not in the default)")
    parser.add_argument("--tasks", nargs="*", default=None, help="subset of tasks")
    parser.add_argument("--archs", nargs="*", default=list(ARCHS))
    parser.add_argument("--n", type=int, default=5000,
                        help="bags per dataset (paper: 5000; Lunar Lander 9762)")
    parser.add_argument("--max-epochs", type=int, default=None, help="override (for a smoke run)")
    parser.add_argument("--data-seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="training-config overrides, e.g. lr=1e-3 schedule=cosine")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--threads", type=int, default=1, help="torch threads per job")
    parser.add_argument("--log-every", type=int, default=0, help="print validation MSE every N epochs")
    parser.add_argument("--json", type=Path, default=None, help="also write all runs here")
    parser.add_argument("--members", type=int, default=None,
                        help="each repeat an ensemble of this many models on its split, scored on their "
                             "mean (as `nmrm train --ensemble M`); member 0 is also reported alone "
                             "(default: the task's `members` in config/mil_training.yaml: Timer 3, else 1)")
    parser.add_argument("--member0-from", type=Path, default=None, metavar="DIR",
                        help="with --members M: take member 0 of each repeat from this one-model --save run "
                             "of the same settings and data (refused otherwise); train only members 1..M-1")
    parser.add_argument("--save", type=Path, default=None, metavar="DIR",
                        help="also save each ensemble's checkpoint as DIR/<task>_<arch>.{pt,json}")
    parser.add_argument("--from-json", type=Path, nargs="*", default=None, metavar="FILE",
                        help="train nothing: print the tables of the runs in these --json files together")
    args = parser.parse_args()
    if args.from_json:
        results = merge_runs(args.from_json)
        order = [t for group in TABLES.values() for t in group]
        report_all(results, tuple(t for t in order if any(r["task"] == t for r in results)),
                   tuple(a for a in ARCHS if any(r["arch"] == a for r in results)))
        ensembles = {(r["task"], r["arch"], r["seconds"]) for r in results}  # one wall time per ensemble
        print(f"\n# runs from {', '.join(map(str, args.from_json))}; training wall time "
              f"{sum(sec for _, _, sec in ensembles):.0f} s in {len(ensembles)} ensemble(s)")
        return
    tasks = tuple(t for table in args.tables for t in TABLES[table])
    if args.tasks:
        tasks = tuple(t for t in tasks if t in args.tasks)
    overrides = parse_settings(args.set)
    if args.max_epochs is not None:
        overrides["max_epochs"] = args.max_epochs
    repeats = list(args.seeds) if args.seeds else list(range(args.repeats))
    jobs = [(t, a, repeats, args.n, args.data_seed, overrides, args.threads, args.log_every, args.save, args.members,
             args.member0_from) for t in tasks for a in args.archs]
    print(f"# {len(jobs)} ensembles of {len(repeats)}: tasks {tasks}, archs {args.archs}, repeats "
          f"(seeds/splits) {repeats}, data seed {args.data_seed}, overrides {overrides}, "
          f"{args.jobs} workers x {args.threads} threads", flush=True)
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for runs in pool.map(run_ensemble, jobs):
            results.extend(runs)
            for res in runs:
                if res.get("members", 1) > 1:
                    print(f"  {res['task']:13s} {res['arch']:15s} repeat {res['repeat']}, mean of {res['members']}: "
                          f"return {res['return_mse']:.4f} reward {res['reward_mse']:.5f} [time profile "
                          f"{res['reward_mse_time_profile']:.5f}]; member 0 alone: return "
                          f"{res['single_return_mse']:.4f} reward {res['single_reward_mse']:.5f} (best epochs up to "
                          f"{res['best_epoch']}/{res['epochs']}{', still improving' if res['still_improving'] else ''}; "
                          f"ensemble {res['seconds']:.0f} s)", flush=True)
                    continue
                print(f"  {res['task']:13s} {res['arch']:15s} seed {res['repeat']}: return {res['return_mse']:.4f} "
                      f"reward {res['reward_mse']:.5f} [time profile {res['reward_mse_time_profile']:.5f}] (best epoch {res['best_epoch']}/{res['epochs']}"
                      f"{', still improving' if res['still_improving'] else ''}; ensemble {res['seconds']:.0f} s)",
                      flush=True)
    report_all(results, tasks, tuple(args.archs))
    print(f"\n# wall time {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
