"""Time to accuracy as a user sees it: `nmrm train` with the defaults, wall time, held-out metrics.

    .venv/bin/python bench/time_to_accuracy.py                       # every task, data seeds 20 21 22
    .venv/bin/python bench/time_to_accuracy.py --tasks key cartpole --seeds 20
    .venv/bin/python bench/time_to_accuracy.py --tag before --config-at 0a6bbee   # the defaults of a commit
    .venv/bin/python bench/time_to_accuracy.py --tag mi01 --set min_improvement=0.01   # the defaults, one changed
    .venv/bin/python bench/time_to_accuracy.py --report

Run (task, s): a screened dataset of data seed s (navigation: 5000 episodes, in the benches' cache
runs/data/; your-own-task examples: 2000, MountainCar 3000, in runs/time_to_accuracy/data/) is written once; then
`nmrm train --data <it> --seed s --split-seed s` runs as a child process with the task's defaults
(config/mil_training.yaml, or that file as it was at --config-at), on whatever cores the machine
has, and its wall time is what is reported: process start, data loading, training and the test
evaluation, as a user waits for it. The checkpoint is then scored on a held-out dataset of data
seed 999 (navigation: 2000 episodes; the others: 1000), the members' mean. Data seeds 20-29 were
never used to choose a default. Nothing else should run meanwhile (the wall time is the figure).

Tasks: key, timer, charger, moving (the paper's navigation tasks); cartpole (examples/
cartpole_crossings.py), mountaincar (examples/mountaincar_swing.py), delivery (the fake robot's
task), patrol and cue_corridor (examples/patrol_robot.py, examples/cue_corridor.py: issue 50's
tasks written after the settings were frozen), each a task spec that takes config/mil_training.yaml's
`your_own_task` entry; and, only
when named, key_pixels ... moving_pixels (the same datasets rendered to 32 x 32 images, issue 53).

Resumes: each run is bench/results/time_to_accuracy/<tag>/<task>_s<s>.json and is skipped when
present (delete it to redo it). The report prints, per task and tag, the worst wall time and the
worst held-out return / reward MSE over the seeds, beside the paper's bars where it has them.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from nmrm_ros.paper import PAPER_RETURN, PAPER_REWARD
from nmrm_ros.datasets.cache import cached_dataset
from nmrm_ros.mil.training import parse_settings

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "time_to_accuracy"
RUNS = ROOT / "runs" / "time_to_accuracy"
HELD_OUT_SEED = 999
NAV = ("key", "timer", "charger", "moving")
EXAMPLES = ROOT / "examples"  # the examples' oracles, and the module envs of OWN (importable: this process and `nmrm train`)
#: your-own-task examples: (task spec, oracle, episodes, held-out episodes)
OWN = {
    "cartpole": ("gym:CartPole-v1,max_episode_steps=200", str(EXAMPLES / "cartpole_crossings.py") + ":oracle",
                 2000, 1000),
    "mountaincar": ("gym:MountainCar-v0", str(EXAMPLES / "mountaincar_swing.py") + ":oracle", 3000, 1000),
    "delivery": ("nmrm_ros.robots.delivery:DeliveryEnv,max_steps=200,xy=0/1", "nmrm_ros.robots.delivery:oracle",
                 2000, 1000),
    # issue 50's held-out tasks, module envs in examples/
    "patrol": ("patrol_robot:PatrolEnv,max_steps=200,xy=0/1", str(EXAMPLES / "patrol_robot.py") + ":oracle",
               2000, 1000),
    "cue_corridor": ("cue_corridor:CueCorridor,max_steps=30", str(EXAMPLES / "cue_corridor.py") + ":oracle",
                     2000, 1000),
}
#: the navigation tasks seen through a rendered top-down image (issue 53; not in the default run)
PIXELS = tuple(f"{t}_pixels" for t in NAV)
TASKS = NAV + tuple(OWN) + PIXELS
NMRM = Path(sys.executable).parent / "nmrm"
sys.path.insert(0, str(EXAMPLES))


def dataset_file(task: str, seed: int, held_out: bool = False) -> Path:
    """The task's dataset of data seed `seed` (written on first use)."""
    from nmrm_ros.datasets import generate_screened

    if task in NAV:  # the benches' shared cache (runs/data/), regenerated when its generator changed
        n = 2000 if held_out else 5000
        cached_dataset(task, n, seed, root=ROOT / "runs" / "data")
        return ROOT / "runs" / "data" / f"{task}_n{n}_s{seed}.npz"
    if task in PIXELS:  # the state task's dataset, rendered (written once: `nmrm train --data` reads a file)
        n = 2000 if held_out else 5000
        path = RUNS / "data" / f"{task}_n{n}_s{seed}.npz"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            cached_dataset(task, n, seed, root=ROOT / "runs" / "data").save(path)
        return path
    spec, oracle, n_train, n_held = OWN[task]
    n = n_held if held_out else n_train
    path = RUNS / "data" / f"{task}_n{n}_s{seed}.npz"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        generate_screened(spec, n, seed=seed, oracle=oracle).save(path)
        print(f"# {path.name}: generated in {time.perf_counter() - t0:.0f} s", flush=True)
    return path


def config_at(rev: str) -> Path:
    """config/mil_training.yaml as it was at commit `rev`, written to runs/time_to_accuracy/."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:config/mil_training.yaml"],
                          check=True, capture_output=True, text=True).stdout
    path = RUNS / f"mil_training_{rev}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def config_with(base: Path, settings: dict, tag: str) -> Path:
    """A copy of the training config `base` with `settings` set in its defaults and in every task's
    entry (so that they apply whatever the task's own entry says), written to runs/time_to_accuracy/."""
    import yaml

    table = yaml.safe_load(base.read_text())  # YAML merges resolved: every entry is whole
    for name, entry in table.items():
        if isinstance(entry, dict) and (name == "defaults" or not name.startswith("_")):
            entry.update(settings)
    path = RUNS / f"mil_training_{tag}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(table, sort_keys=False))
    return path


def run(task: str, seed: int, tag: str, config: Path | None) -> dict:
    from nmrm_ros.datasets import TrajectoryDataset
    from nmrm_ros.mil import evaluate, load_checkpoint

    data, held = dataset_file(task, seed), dataset_file(task, HELD_OUT_SEED, held_out=True)
    out = RUNS / tag / f"{task}_s{seed}"
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [str(NMRM), "train", "--data", str(data), "--seed", str(seed), "--split-seed", str(seed), "--out", str(out)]
    if config is not None:
        cmd += ["--config", str(config)]
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(EXAMPLES), os.environ.get("PYTHONPATH")])))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{task} seed {seed}: nmrm train failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    model, meta = load_checkpoint(out)
    on_held = evaluate(model, TrajectoryDataset.load(held))
    training = meta.metrics
    res = {"task": task, "data_seed": seed, "weight_seed": seed, "split_seed": seed, "held_out_seed": HELD_OUT_SEED,
           "tag": tag, "config": str(config) if config else "config/mil_training.yaml", "command": " ".join(cmd),
           "wall_seconds": wall, "held_return_mse": on_held["return_mse"], "held_reward_mse": on_held["reward_mse"],
           "epochs": training.get("epochs_run"), "best_epochs": training.get("best_epochs"),
           "still_improving": training.get("still_improving"), "stdout_tail": proc.stdout[-600:]}
    return res


def _bar(table: dict, task: str) -> float:
    """The paper's bar for the CSC model on `task`: mean + 2 SEM."""
    mean, sem = table["csc_lstm"][task]
    return mean + 2 * sem


def report(tags: list) -> str:
    lines = ["# bench/time_to_accuracy.py: `nmrm train --data <data seed s> --seed s --split-seed s`, wall time on "
             "this machine; held-out: data seed 999; worst [median] over the seeds",
             f"{'task':12s} {'tag':10s} {'seeds':12s} {'wall s':>14s} {'held-out return MSE':>22s} "
             f"{'held-out reward MSE':>22s}  paper bars  epochs  still improving at the cap"]
    for task in TASKS:
        for tag in tags:
            files = sorted((RESULTS / tag).glob(f"{task}_s*.json"))
            if not files:
                continue
            rs = [json.loads(f.read_text()) for f in files]
            w = [r["wall_seconds"] for r in rs]
            ret = [r["held_return_mse"] for r in rs]
            rew = [r["held_reward_mse"] for r in rs]
            base = task.removesuffix("_pixels")
            bars = f"{_bar(PAPER_RETURN, base):.3g} / {_bar(PAPER_REWARD, base):.3g}" if base in NAV else "-"
            still = [r["data_seed"] for r in rs if r.get("still_improving") and any(r["still_improving"])]
            epochs = max((r.get("epochs") or 0) for r in rs)
            lines.append(f"{task:12s} {tag:10s} {str([r['data_seed'] for r in rs]):12s} "
                         f"{max(w):6.0f} [{np.median(w):5.0f}] {max(ret):10.4f} [{np.median(ret):8.4f}] "
                         f"{max(rew):10.5f} [{np.median(rew):8.5f}]  {bars:>10s}  {epochs:6d}  {still or ''}")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=list(NAV + tuple(OWN)), choices=TASKS)
    p.add_argument("--seeds", nargs="+", type=int, default=[20, 21, 22])
    p.add_argument("--tag", default="head", help="results directory name (bench/results/time_to_accuracy/TAG)")
    p.add_argument("--config-at", default=None, help="train with config/mil_training.yaml as at this commit")
    p.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                   help="train with these settings changed in every task's entry (needs its own --tag)")
    p.add_argument("--report", action="store_true", help="print the table of what is there and stop")
    a = p.parse_args()
    tags = sorted(d.name for d in RESULTS.glob("*") if d.is_dir()) if RESULTS.is_dir() else []
    if a.report:
        print(report(tags))
        return
    config = config_at(a.config_at) if a.config_at else None
    if a.set:
        if a.tag == "head":
            raise SystemExit("--set: give the run its own --tag (head is the defaults)")
        base = config or ROOT / "config" / "mil_training.yaml"
        config = config_with(base, parse_settings(a.set), a.tag)
    for task in a.tasks:
        for seed in a.seeds:
            path = RESULTS / a.tag / f"{task}_s{seed}.json"
            if path.is_file():
                continue
            res = run(task, seed, a.tag, config)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(res, indent=1))
            print(f"{task} s{seed} [{a.tag}]: {res['wall_seconds']:.0f} s, held-out return MSE "
                  f"{res['held_return_mse']:.4f}, reward MSE {res['held_reward_mse']:.5f}, epochs {res['epochs']}",
                  flush=True)
    print(report(sorted({a.tag, *tags})))


if __name__ == "__main__":
    main()
