"""Agents on what the reward model serves: [h', c'] (the default) against h' alone (the paper's
choice), on the same CSC models with the same agent seeds, beside the oracle with its hidden state.

    .venv/bin/python bench/served_state_agents.py                        # 4 tasks, 3 seeds
    .venv/bin/python bench/served_state_agents.py --tasks charger --seeds 0 1 2 --jobs 2

Per task, one CSC model (the task's defaults in config/mil_training.yaml: Timer and Moving the
mean of 3) is trained on a screened dataset of data seed --data-seed (default 100: none of the
benchmarks' data seeds), weights and split seeded the same; agent seed s (double DQN, 400
episodes, config/rl.yaml; SB3 seed s, episode e seeded s + e) is trained on it once observing
[s_t, h'_{t+1}, tanh c'_{t+1}] ("h_tanh_c", the default), once the raw [s_t, h'_{t+1}, c'_{t+1}]
("h_c"), once [s_t, h'_{t+1}] ("h"), and on the oracle with its hidden
state. Every agent is judged by the oracle: its final oracle return (mean of its last 50 training
episodes) and its greedy policy's oracle return on 50 new episodes (seeds 10^8...).

Resumes: models and agents already in --work are reused (delete a run's directory to redo it).
Results: bench/results/served_state_agents.txt (and .json).
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
from nmrm_ros.tasks import NAVIGATION_TASKS

ROOT = Path(__file__).resolve().parents[1]
TASKS = NAVIGATION_TASKS
KINDS = ("h_tanh_c", "h_c", "h", "oracle")  # the served states (nmrm_ros.mil.served_state), the oracle
LABELS = {"h_tanh_c": "CSC, [h', tanh c'] served", "h_c": "CSC, [h', c'] served", "h": "CSC, h' served",
          "oracle": "oracle with hidden state"}


def model_stem(work: Path, task: str, data_seed: int) -> Path:
    return work / "models" / f"{task}_csc_d{data_seed}"


def train_model(job: tuple) -> dict:
    """Train (or reuse) the task's CSC model; its test metrics."""
    work, task, data_seed, overrides = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.mil import DataSource, load_train_config
    from nmrm_ros.mil.pipeline import fit

    out = model_stem(work, task, data_seed)
    if out.with_suffix(".json").is_file():
        return json.loads(out.with_suffix(".json").read_text())["metrics"]
    ds = generate_screened(task, 5000, seed=data_seed)
    cfg = load_train_config(task, seed=data_seed, **overrides)
    source = DataSource.generated(task, 5000, data_seed)
    fit(ds, "csc_lstm", cfg, cfg.members, split_seed=data_seed, out=out, progress=False,
                       data_source=source)
    return json.loads(out.with_suffix(".json").read_text())["metrics"]


def train_agent_job(job: tuple) -> dict:
    """Train (or reuse) one agent and judge its greedy policy; its figures."""
    work, task, data_seed, kind, seed, episodes = job
    from nmrm_ros.rl.evaluation import evaluate_agent
    from nmrm_ros.rl.training import train_agent

    out = work / "agents" / f"{task}_{kind}_seed{seed}"
    result_file = out / "result.json"
    if result_file.is_file():
        return json.loads(result_file.read_text())
    checkpoint = model_stem(work, task, data_seed) if kind != "oracle" else None
    reward = "oracle" if kind == "oracle" else "model"
    t0 = time.perf_counter()
    run = train_agent(task, reward, checkpoint, episodes=episodes, seed=seed, out=out, progress=False,
                      **({"served": kind} if kind != "oracle" else {}))
    seconds = time.perf_counter() - t0
    greedy = evaluate_agent(out / "policy.zip", task, checkpoint=checkpoint, episodes=50)
    result = {"task": task, "kind": kind, "seed": seed, "data_seed": data_seed, "episodes": episodes,
              "final_oracle_return": run.curve.final_oracle_return(),
              "final_learnt_return": float(np.mean([r.learnt_return for r in run.curve.records[-50:]])),
              "greedy_oracle_return": float(greedy.returns.mean()),
              "random_oracle_return": float(greedy.random_returns.mean()), "seconds": seconds}
    result_file.write_text(json.dumps(result, indent=1))
    return result


def report(results: list, models: dict, tasks: list) -> str:
    lines = ["# final oracle return (mean of the last 50 of 400 training episodes) and the greedy policy's",
             "# oracle return on 50 new episodes; mean over agent seeds [worst seed]; ratio: median CSC / median oracle",
             f"{'task':8s} {'reward':28s} {'final':>18s} {'greedy':>18s} {'seeds':>6s} {'ratio':>6s}"]
    for task in tasks:
        m = models.get(task)
        if m:
            test = m.get("test") or {}
            lines.append(f"{task}: model test return MSE {test.get('return_mse', float('nan')):.4f}, "
                         f"reward MSE {test.get('reward_mse', float('nan')):.5f}")
        oracle = [r["greedy_oracle_return"] for r in results if r["task"] == task and r["kind"] == "oracle"]
        for kind in KINDS:
            rs = [r for r in results if r["task"] == task and r["kind"] == kind]
            if not rs:
                continue
            final = [r["final_oracle_return"] for r in rs]
            greedy = [r["greedy_oracle_return"] for r in rs]
            ratio = (f"{np.median(greedy) / np.median(oracle):.2f}" if oracle and kind != "oracle"
                     and np.median(oracle) > 0 else "")
            lines.append(f"{'':8s} {LABELS[kind]:28s} {np.mean(final):9.2f} [{min(final):6.2f}] "
                         f"{np.mean(greedy):9.2f} [{min(greedy):6.2f}] {len(rs):6d} {ratio:>6s}")
            lines.append(f"{'':37s} per seed: " + ", ".join(
                f"{r['seed']}: {r['final_oracle_return']:.1f}/{r['greedy_oracle_return']:.1f}" for r in rs))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=list(TASKS), choices=TASKS)
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--kinds", nargs="*", default=list(KINDS), choices=KINDS)
    parser.add_argument("--data-seed", type=int, default=100)
    parser.add_argument("--episodes", type=int, default=400)
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "served_state_agents")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "served_state_agents.txt")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="training-config overrides of the models (use a --work of their own)")
    args = parser.parse_args()
    from nmrm_ros.mil.training import parse_settings

    overrides = parse_settings(args.set)
    start = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        models = dict(zip(args.tasks, pool.map(train_model, [(args.work, t, args.data_seed, overrides) for t in args.tasks])))
        jobs = [(args.work, t, args.data_seed, k, s, args.episodes) for t in args.tasks for s in args.seeds
                for k in args.kinds]
        results = []
        for r in pool.map(train_agent_job, jobs):
            results.append(r)
            print(f"  {r['task']} {r['kind']} seed {r['seed']}: final {r['final_oracle_return']:.2f}, greedy "
                  f"{r['greedy_oracle_return']:.2f} ({r['seconds']:.0f} s)", flush=True)
    text = report(results, models, args.tasks)
    print(text)
    print(f"# wall time {time.perf_counter() - start:.0f} s")
    command = ['bench/served_state_agents.py', '--tasks', *args.tasks, '--kinds', *args.kinds]
    command += ['--set', *args.set] if args.set else []
    args.out.write_text(text + f"\n# {' '.join(command)}, seeds {args.seeds}, data seed {args.data_seed}\n")
    args.out.with_suffix(".json").write_text(json.dumps({"models": models, "agents": results}, indent=1))


if __name__ == "__main__":
    main()
