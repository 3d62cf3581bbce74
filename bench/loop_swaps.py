"""What a model swap does to a learning agent: a finished loop's agent replayed against its saved models.

    PYTHONPATH=examples .venv/bin/python bench/loop_swaps.py runs/your_own_task/charger_new/loops/loop_4x500_s31 \\
        --task charger --seed 31
    .venv/bin/python bench/loop_swaps.py --report

`nmrm loop` (nmrm_ros.rl.reward_model_loop) trains model k on the labels so far and swaps it in
under the agent at episode k E / R. This replays the agent alone (the same seed, episodes, RL
settings, swaps and catch-up; no labelling, no training: the loop's own model_k checkpoints)
twice:

- `recorded`: each model serving the member its checkpoint records (the loop as it ran);
- `kept`: every model serving model 0's member, as a warm-started retrain does since 2026-12-07
  (nmrm_ros.mil.retrain): the served hidden state stays the units the agent learnt on.

Figures per swap: the agent's oracle return in the 20 episodes before, the first 10 and 30 after,
the lowest mean of 10 consecutive episodes in the 50 after; the last 50 episodes; the collapse
report. The replay is not the loop's own run (its labelling episodes drew from the agent's
random generators), but both variants share everything up to the first swap whose member differs.

Resumes: a run's figures are bench/results/loop_swaps/<name>_<variant>.json (name: the loop
directory's parent and own name), skipped when present.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "loop_swaps"
WORK = ROOT / "runs" / "loop_swaps"
VARIANTS = ("recorded", "kept")


def loop_models(loop: Path) -> list:
    models = []
    while (loop / f"model_{len(models)}.pt").is_file():
        models.append(loop / f"model_{len(models)}.pt")
    if not models:
        sys.exit(f"loop_swaps: no model_0.pt in {loop}: give a finished `nmrm loop` directory")
    return models


def serving_kept_copy(loop: Path, out: Path) -> Path:
    """A copy of the loop's checkpoints with every model serving model 0's member."""
    import torch

    out.mkdir(parents=True, exist_ok=True)
    first = None
    for pt in loop_models(loop):
        state = torch.load(pt, weights_only=False, map_location="cpu")
        first = int(state["serving_member"]) if first is None else first
        state["serving_member"].fill_(first)
        torch.save(state, out / pt.name)
        meta = json.loads(pt.with_suffix(".json").read_text())
        old = hashlib.sha256(pt.read_bytes()).hexdigest()
        meta = json.loads(json.dumps(meta).replace(old, hashlib.sha256((out / pt.name).read_bytes()).hexdigest()))
        meta["ensemble"]["serving_member"] = first
        (out / pt.with_suffix(".json").name).write_text(json.dumps(meta, indent=1))
    return out


def replay(models_dir: Path, task: str, seed: int, oracle: str, episodes: int, rounds: int) -> dict:
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.mil.checkpoint import load_checkpoint
    from nmrm_ros.rl.config import algorithm_name, load_rl_config, trust_settings
    from nmrm_ros.rl.reward_model_loop import LoopRounds
    from nmrm_ros.rl.training import train_agent

    boundaries = [round(episodes * k / rounds) for k in range(1, rounds)]
    catch_up = trust_settings(load_rl_config(algorithm_name(task), task=task))["catch_up_steps"]
    t0 = time.perf_counter()
    callback = LoopRounds(boundaries, lambda k, agent: str(models_dir / f"model_{k}.pt"), catch_up)
    run = train_agent(task, "model", checkpoint=str(models_dir / "model_0.pt"), episodes=episodes,
                      seed=seed, progress=False, oracle=oracle, callback=callback)
    r = np.array([x.oracle_return for x in run.curve.records])
    members = [int(load_checkpoint(models_dir / f"model_{k}.pt", task=task)[0].serving_member)
               for k in range(rounds)]
    swaps = [{"episode": b, "member": f"{members[k]}->{members[k + 1]}", "before_20": float(r[b - 20:b].mean()),
              "after_10": float(r[b:b + 10].mean()), "after_30": float(r[b:b + 30].mean()),
              "lowest_10_in_50": float(min(r[i:i + 10].mean() for i in range(b, min(b + 41, len(r) - 9))))}
             for k, b in enumerate(boundaries)]
    return {"swaps": swaps, "last_50": float(r[-50:].mean()), "collapsed": bool(run.collapse and run.collapse.collapsed),
            "collapse": run.collapse.summary() if run.collapse else "", "seconds": time.perf_counter() - t0,
            "catch_up_steps": catch_up}


def report() -> None:
    rows = sorted(RESULTS.glob("*.json"))
    print("# bench/loop_swaps.py: a loop's agent replayed against its saved models; oracle return "
          "20 episodes before -> first 10 after each swap (lowest 10-episode mean in the 50 after); last 50")
    for f in rows:
        d = json.loads(f.read_text())
        swaps = ", ".join(f"{s['episode']} [{s['member']}]: {s['before_20']:.1f} -> {s['after_10']:.1f} "
                          f"({s['lowest_10_in_50']:.1f})" for s in d["swaps"])
        print(f"{f.stem:40s} {swaps}; last 50 {d['last_50']:.1f}; {'COLLAPSED' if d['collapsed'] else 'no collapse'}"
              f" ({d['seconds']:.0f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("loop", nargs="?", type=Path, help="a finished `nmrm loop` directory")
    parser.add_argument("--task", help="the loop's task (its loop.json names the task's short name only)")
    parser.add_argument("--seed", type=int, help="the loop's agent seed (default: its loop.json's)")
    parser.add_argument("--oracle", default=None, help="default: the loop's (its loop.json)")
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--report", action="store_true")
    args = parser.parse_args()
    if args.report:
        return report()
    if args.loop is None or not (args.loop / "loop.json").is_file():
        parser.error("give a finished `nmrm loop` directory (with loop.json)")
    meta = json.loads((args.loop / "loop.json").read_text())
    task = args.task or meta["task"]
    seed = meta["seed"] if args.seed is None else args.seed
    oracle = meta.get("oracle", "") if args.oracle is None else args.oracle
    if len(loop_models(args.loop)) < int(meta["rounds_planned"]):
        parser.error(f"{args.loop} holds {len(loop_models(args.loop))} models of {meta['rounds_planned']} rounds: "
                     "give a finished `nmrm loop` directory")
    name = f"{args.loop.resolve().parent.parent.name}_{args.loop.name}"
    RESULTS.mkdir(parents=True, exist_ok=True)
    for variant in args.variants:
        out = RESULTS / f"{name}_{variant}.json"
        if out.is_file():
            print(f"# {out.name}: done, skipped")
            continue
        models = args.loop if variant == "recorded" else serving_kept_copy(args.loop, WORK / name)
        result = replay(models, task, seed, oracle, int(meta["episodes"]), int(meta["rounds_planned"]))
        out.write_text(json.dumps({"loop": str(args.loop), "task": task, "seed": seed, "oracle": oracle,
                                   "variant": variant, **result}, indent=1))
        print(f"# {out.name}: written", flush=True)
    report()


if __name__ == "__main__":
    main()
