"""Against the peers: imitation's preference comparisons beside our CSC model, on our tasks, from the
same teacher and the same budgets of comparisons (issue 55).

    .venv/bin/python bench/imitation_peer.py --setup          # (re)build imitation's pinned venv
    .venv/bin/python bench/imitation_peer.py --tasks key --comparisons 1000 4000 --seeds 0 1 2 --jobs 2
    .venv/bin/python bench/imitation_peer.py --report

`--setup` builds runs/peers/imitation-venv from bench/peers/imitation-requirements.txt (imitation
1.0.1 with the gymnasium 0.29 / stable-baselines3 2.2 it pins, torch 2.13.0 CPU; all pinned) and
installs this source tree into it without dependencies, so our tasks reach imitation through their
Gymnasium API (`nmrm_ros.rl.wrappers.make_reward_env`), not through copies. It runs again only when
the requirements or our sources changed (a stamp in the venv). Nothing of imitation enters .venv.

Cells (task, comparisons n, teacher, seed r):
- `imitation` (and `imitation_ensemble`, `--variants`): bench/peers/imitation_run.py in the peer
  venv: imitation's `train_preference_comparisons` script with its defaults (its reward net learns
  from n comparisons of its own agent's rollouts, its PPO agent trains on that net for
  `--timesteps` steps, imitation's default 10^6), seed r, one thread;
- `imitation_offline`: the same, but its comparisons are of the episodes our model learns from
  (its script's `trajectory_path`: the 5000 screened random-policy episodes of data seed r, which
  its fragmenter pairs at random) instead of its agent's; then its agent on that net, as its docs
  train one on a learnt reward: its reward net and ours from the same kind of data;
- `ppo_oracle`: no reward learning (n is not used): imitation's agent (PPO as its script makes it)
  on the oracle's reward itself, observing the state only, `--timesteps` steps: what its agent
  could reach were its reward net perfect;
- `csc_lstm`: our offline model from n comparisons of random-policy episodes (data seed r, the
  preference grid's protocol, `bench/preferences.py`: the task's default model, feedback preferences),
  then our DQN agent on it (config/rl.yaml, 400 episodes, agent seed r);
- `transformer`: the same with our fifth architecture, the causal transformer (`--arch transformer`,
  docs/guide/models.md), instead of the CSC LSTM;
- `dqn_oracle`: our DQN agent on the oracle's reward with its hidden state (the oracle-with-hidden
  agent our issues compare with): what our agent reaches were our model perfect.
Teachers: our `SimulatedTeacher`, perfect (beta = inf) or noisy (beta = 1, mistake 0.1), for both.
Judged alike: held-out preference accuracy and reward correlation (Pearson r per step, and centred)
on 2000 screened episodes of data seed 999 (`nmrm_ros.mil.evaluation`; screened: random-policy
episodes kept by the oracle's trajectory classes, paper App. D.2, as our training data is, not as
imitation's agent's rollouts are — `imitation_offline` learns from such episodes too), and the
agent's greedy oracle return over 50 episodes with episode seeds 10^8..
(`nmrm_ros.rl.evaluation.evaluate_agent`): our agent's last policy, as imitation's final PPO (the
policy `train_agent` keeps, chosen with the oracle's return among others, is reported beside it).
Seconds: wall time of the cell on one thread (training and agent; the judging not included).

Resumes: each cell is bench/results/peers/imitation/<kind>_<task>_<teacher>_n<n>_s<r>.json; what
exists is not run again; --report prints and writes table.txt from what exists.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from nmrm_ros.datasets.preference_teacher import TEACHERS as NAMED_TEACHERS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "peers" / "imitation"
RUNS = ROOT / "runs" / "peers"
VENV = RUNS / "imitation-venv"
REQUIREMENTS = ROOT / "bench" / "peers" / "imitation-requirements.txt"
RUNNER = ROOT / "bench" / "peers" / "imitation_run.py"
TASKS = ("key", "timer", "charger")
KINDS = ("imitation", "imitation_ensemble", "imitation_offline", "ppo_oracle", "csc_lstm", "transformer", "dqn_oracle")
OURS = ("csc_lstm", "transformer", "dqn_oracle")  # run in this venv; the others in imitation's
REFERENCES = ("ppo_oracle", "dqn_oracle")  # agents on the oracle's reward: no teacher, no comparisons
TEACHER_KNOBS = NAMED_TEACHERS  # the simulated teacher's knobs, also read by the runner in imitation's venv
TEACHERS = tuple(TEACHER_KNOBS)
HELD_OUT_SEED, HELD_OUT_N = 999, 2000
EVAL_EPISODES, AGENT_EPISODES = 50, 400


def source_digest() -> str:
    """sha256 of the requirements and of every source file of nmrm_ros (what the venv holds)."""
    h = hashlib.sha256(REQUIREMENTS.read_bytes())
    for path in sorted((ROOT / "nmrm_ros").rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            h.update(str(path.relative_to(ROOT)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def setup(force: bool = False) -> Path:
    """Build (or update) the peer venv; returns its python. Pinned requirements only."""
    python = VENV / "bin" / "python"
    stamp = VENV / "nmrm-peer-stamp"
    digest = source_digest()
    if not force and stamp.is_file() and stamp.read_text() == digest:
        return python
    if not python.is_file():
        subprocess.run([sys._base_executable, "-m", "venv", str(VENV)], check=True)
    pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    subprocess.run(pip + ["-r", str(REQUIREMENTS)], check=True)
    subprocess.run(pip + ["--no-deps", "--force-reinstall", str(ROOT)], check=True, cwd=RUNS)
    stamp.write_text(digest)
    return python


def cell_name(kind: str, task: str, teacher: str, n: int, r: int) -> str:
    return f"{kind}_{task}_{teacher}_n{n}_s{r}"


def held_out(task: str):
    from nmrm_ros.datasets.cache import cached_dataset

    return cached_dataset(task, HELD_OUT_N, HELD_OUT_SEED)


def score(ds, rewards: np.ndarray) -> dict:
    """Our held-out metrics of per-step rewards (n, L) predicted for the episodes of `ds`."""
    from nmrm_ros.mil.evaluation import centred, correlation, preference_accuracy

    mask = np.arange(ds.rewards.shape[1])[None, :] < ds.lengths[:, None]
    steps = np.broadcast_to(np.arange(ds.rewards.shape[1]), mask.shape)[mask]
    pred, true = rewards[mask], ds.rewards[mask]
    return {"preference_accuracy": preference_accuracy((rewards * mask).sum(1), ds.returns)[0],
            "reward_correlation": correlation(pred, true),
            "reward_correlation_centred": correlation(centred(pred, steps), centred(true, steps))}


def export_episodes(task: str, r: int) -> Path:
    """The 5000 screened episodes of data seed r (what our model of run r learns from) as an npz
    the peer venv reads."""
    from nmrm_ros.datasets.cache import cached_dataset

    path = RUNS / "data" / f"{task}_n5000_s{r}.npz"
    if not path.is_file():
        ds = cached_dataset(task, 5000, r)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, states=ds.states, actions=ds.actions, final_states=ds.final_states, rewards=ds.rewards,
                 lengths=ds.lengths)
        os.replace(tmp, path)
    return path


def run_imitation(job: tuple) -> dict:
    kind, task, teacher, n, r, timesteps, python = job
    name = cell_name(kind, task, teacher, n, r)
    out = RUNS / "imitation" / name
    ds = held_out(task)
    held = RUNS / "held" / f"{task}_n{HELD_OUT_N}_s{HELD_OUT_SEED}.npz"
    if not held.is_file():
        held.parent.mkdir(parents=True, exist_ok=True)
        tmp = held.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, states=ds.states, actions=ds.actions, final_states=ds.final_states, lengths=ds.lengths)
        os.replace(tmp, held)
    cmd = [str(python), "-W", "ignore", str(RUNNER), "--task", task, "--comparisons", str(max(n, 1)),
           "--teacher", teacher if teacher in TEACHERS else "perfect",
           "--seed", str(r), "--timesteps", str(timesteps), "--held-out", str(held), "--out", str(out)]
    if kind == "imitation_ensemble":
        cmd.append("--ensemble")
    if kind == "ppo_oracle":
        cmd.append("--true-reward")
    if kind == "imitation_offline":
        cmd += ["--trajectories", str(export_episodes(task, r))]
    env = dict(os.environ, OMP_NUM_THREADS="1", TQDM_DISABLE="1")
    log = out.with_suffix(".log")
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as f:
        done = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{name}: the peer run failed (exit {done.returncode}); its log: {log}")
    res = json.loads((out / "result.json").read_text())
    held_scores = score(ds, np.load(out / "held_rewards.npy")) if kind != "ppo_oracle" else None
    res.update(kind=kind, command=" ".join(cmd[3:]).replace(str(ROOT) + "/", ""), held=held_scores,
               seconds=res["wall_seconds"])
    if kind == "ppo_oracle":  # no teacher, no comparisons
        res.update(teacher="none", comparisons=0, teacher_knobs=None)
    return save(name, res)


def run_ours(job: tuple) -> dict:
    """Our model (CSC LSTM or transformer) from n comparisons (`our_model`) and our DQN agent on it; or
    (`dqn_oracle`) our DQN agent on the oracle with its hidden state."""
    kind, task, teacher, n, r, _, _ = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl import train_agent

    name = cell_name(kind, task, teacher, n, r)
    if kind == "dqn_oracle":
        agent_dir = RUNS / "ours_agents" / name
        seconds = train_once(agent_dir, lambda: train_agent(task, "oracle", episodes=AGENT_EPISODES, seed=r,
                                                           out=agent_dir, progress=False))
        return save(name, {"kind": kind, "task": task, "teacher": "none", "comparisons": 0, "seed": r, "held": None,
                           **judge_ours(agent_dir, task, None), "seconds": seconds, "threads": 1,
                           "agent_episodes": AGENT_EPISODES,
                           "command": f"bench/imitation_peer.py --kinds dqn_oracle --tasks {task} --seeds {r}"})
    model, checkpoint = our_model(kind, task, teacher, n, r)
    agent_dir = RUNS / "ours_agents" / name
    agent_seconds = train_once(agent_dir, lambda: train_agent(task, "model", checkpoint=checkpoint,
                                                              episodes=AGENT_EPISODES, seed=r, out=agent_dir,
                                                              progress=False))
    res = {"kind": kind, "task": task, "teacher": teacher, "comparisons": n, "seed": r,
           "held": {k: model["held"][k] for k in ("preference_accuracy", "reward_correlation",
                                                   "reward_correlation_centred")},
           **judge_ours(agent_dir, task, checkpoint),
           "model_cpu_seconds": model["seconds"], "agent_seconds": agent_seconds,
           "seconds": model["seconds"] + agent_seconds, "threads": 1, "agent_episodes": AGENT_EPISODES,
           "command": f"bench/imitation_peer.py --kinds {kind} --tasks {task} --teachers {teacher} "
                      f"--comparisons {n} --seeds {r}"}
    return save(name, res)


def our_model(arch: str, task: str, teacher: str, n: int, r: int) -> tuple[dict, Path]:
    """({"held": our metrics, "seconds": CPU seconds of training}, checkpoint) of our default model
    of architecture `arch` (the task's training config) from n comparisons of the teacher (the preference grid's protocol, bench/preferences.py): the
    screened 5000 episodes of data seed r, n pairs drawn and answered with seed r, split r, weight
    seeds r + 1000 j. A checkpoint already in runs/peers/models is reused."""
    from nmrm_ros.datasets.cache import cached_dataset
    from nmrm_ros.datasets.preference_teacher import SimulatedTeacher, with_preferences
    from nmrm_ros.mil import Run, evaluate, fit, load_train_config

    checkpoint = RUNS / "models" / cell_name(arch, task, teacher, n, r)
    record = checkpoint.with_suffix(".seconds.json")
    if checkpoint.with_suffix(".pt").is_file() and record.is_file():
        run, seconds = Run.load(checkpoint), float(json.loads(record.read_text())["seconds"])
    else:
        ds = with_preferences(cached_dataset(task, 5000, r), n, SimulatedTeacher(**TEACHER_KNOBS[teacher]), seed=r)
        cfg = load_train_config(task, seed=r, feedback="preferences")
        t0 = time.process_time()
        run = fit(ds, arch, cfg, members=cfg.members, split_seed=r,
                  offsets=[1000 * j for j in range(cfg.members)], progress=False)
        seconds = time.process_time() - t0
        run.save(checkpoint)
        record.write_text(json.dumps({"seconds": seconds}))
    return {"held": evaluate(run.model, held_out(task)), "seconds": seconds}, checkpoint.with_suffix(".pt")


def train_once(agent_dir: Path, train) -> float:
    """Wall seconds of `train()` (our agent into agent_dir); an agent already there (agent.json
    written last) is not trained again: its seconds are read back."""
    record = agent_dir / "seconds.json"
    if (agent_dir / "agent.json").is_file() and record.is_file():
        return float(json.loads(record.read_text())["seconds"])
    t0 = time.perf_counter()
    train()
    seconds = time.perf_counter() - t0
    record.write_text(json.dumps({"seconds": seconds}))
    return seconds


def judge_ours(agent_dir: Path, task: str, checkpoint: Path | None) -> dict:
    """Our agent's greedy oracle returns: its last policy (the figure, as imitation's final PPO is
    judged) and the kept one (`policy.zip`: train_agent keeps the best of every 20 episodes by the
    worse of its learnt and its oracle return, a choice imitation's agent does not get)."""
    from nmrm_ros.rl.evaluation import evaluate_agent

    reward = "model" if checkpoint is not None else "oracle"
    last = agent_dir / "last_policy.zip"
    last = last if last.is_file() else agent_dir / "policy.zip"  # the last is the kept one
    judged = evaluate_agent(last, task, checkpoint=checkpoint, episodes=EVAL_EPISODES, reward=reward)
    kept = evaluate_agent(agent_dir / "policy.zip", task, checkpoint=checkpoint, episodes=EVAL_EPISODES, reward=reward)
    return {"agent_greedy_oracle_returns": [float(x) for x in judged.returns],
            "agent_greedy_oracle_return": float(np.mean(judged.returns)),
            "kept_policy_greedy_oracle_return": float(np.mean(kept.returns)),
            "random_policy_oracle_return": float(np.mean(judged.random_returns))}


def save(name: str, res: dict) -> dict:
    RESULTS.mkdir(parents=True, exist_ok=True)
    tmp = RESULTS / f"{name}.{os.getpid()}.json.tmp"
    tmp.write_text(json.dumps(res, indent=1))
    os.replace(tmp, RESULTS / f"{name}.json")
    return res


def run_cell(job: tuple) -> dict:
    return run_ours(job) if job[0] in OURS else run_imitation(job)


def report() -> str:
    cells = [json.loads(p.read_text()) for p in sorted(RESULTS.glob("*.json"))]
    lines = ["# bench/imitation_peer.py: imitation 1.0.1's preference comparisons (its defaults; `imitation_ensemble`: "
             "its reward_ensemble config) vs our CSC LSTM and transformer, same teacher, same number of comparisons n",
             "# held-out: 2000 screened episodes of data seed 999; agent: greedy oracle return over 50 episodes "
             "(seeds 10^8..); mean [worst] over seeds; s: wall seconds per cell on one thread"]
    lines.append(f"{'task':8} {'teacher':8} {'n':>5} {'model':19} {'seeds':8} {'pref. accuracy':>16} "
                 f"{'reward corr.':>16} {'agent oracle return':>22} {'random':>7} {'s/cell':>7} {'agent steps':>11}")
    groups: dict = {}
    for c in cells:
        groups.setdefault((c["task"], c["teacher"], c["comparisons"], c["kind"]), []).append(c)
    order = {k: i for i, k in enumerate(KINDS)}
    for (task, teacher, n, kind), cs in sorted(groups.items(), key=lambda kv: (TASKS.index(kv[0][0]) if kv[0][0] in TASKS else 99,
                                                                             kv[0][1], kv[0][2], order[kv[0][3]])):
        def mw(values):
            return f"{np.mean(values):6.3f} [{min(values):6.3f}]" if values else "-"
        acc = [c["held"]["preference_accuracy"] for c in cs if c["held"]]
        corr = [c["held"]["reward_correlation"] for c in cs if c["held"]]
        ret = [c["agent_greedy_oracle_return"] for c in cs]
        steps = cs[0].get("timesteps", cs[0].get("agent_episodes", 0) * 100)
        seeds = ",".join(str(c["seed"]) for c in sorted(cs, key=lambda c: c["seed"]))
        lines.append(f"{task:8} {teacher:8} {n:5d} {kind:19} {seeds:8} {mw(acc):>16} {mw(corr):>16} "
                     f"{np.mean(ret):8.2f} [{min(ret):8.2f}]  {np.mean([c['random_policy_oracle_return'] for c in cs]):6.2f} "
                     f"{np.mean([c['seconds'] for c in cs]):7.0f} {steps:11d}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--setup", action="store_true", help="build or update the peer venv, then stop")
    ap.add_argument("--tasks", nargs="*", default=["key"], choices=TASKS)
    ap.add_argument("--kinds", nargs="*", default=["imitation", "csc_lstm"], choices=KINDS)
    ap.add_argument("--teachers", nargs="*", default=["perfect"], choices=TEACHERS)
    ap.add_argument("--comparisons", nargs="*", type=int, default=[1000, 4000])
    ap.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    ap.add_argument("--timesteps", type=int, default=1_000_000,
                    help="imitation's agent's environment steps (its script's default: 10^6)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--report", action="store_true", help="run nothing: print and write the table")
    args = ap.parse_args()
    bad = [f"--{k} {v}" for k, v in (("jobs", args.jobs), ("timesteps", args.timesteps)) if v < 1]
    bad += [f"--comparisons {n}" for n in args.comparisons if n < 1]
    if bad:
        sys.exit(f"error: {', '.join(bad)}: must be >= 1")
    if args.setup:
        print(f"peer venv ready: {setup(force=True).parent.parent}")
        return
    if not args.report:
        python = setup() if any(k.startswith(("imitation", "ppo")) for k in args.kinds) else None
        cells = [(k, t, tch, n, r) for n in sorted(args.comparisons) for r in args.seeds for t in args.tasks
                 for tch in args.teachers for k in args.kinds if k not in REFERENCES]
        cells = [(k, t, "none", 0, r) for k in REFERENCES if k in args.kinds for r in args.seeds for t in args.tasks] + cells
        jobs = [(*c, args.timesteps, python) for c in cells if not (RESULTS / f"{cell_name(*c)}.json").is_file()]
        print(f"# {len(jobs)} cells to run (finished ones skipped)", flush=True)
        held = lambda res, key: f"{res['held'][key]:.3f}" if res["held"] else "-"  # noqa: E731
        with ProcessPoolExecutor(args.jobs) as pool:
            for res in pool.map(run_cell, jobs):
                print(f"  {cell_name(res['kind'], res['task'], res['teacher'], res['comparisons'], res['seed'])}: "
                      f"held-out preference accuracy {held(res, 'preference_accuracy')}, reward correlation "
                      f"{held(res, 'reward_correlation')}, agent's greedy oracle return "
                      f"{res['agent_greedy_oracle_return']:.2f} ({res['seconds']:.0f} s)", flush=True)
    text = report()
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "table.txt").write_text(text + "\n# command: .venv/bin/python bench/imitation_peer.py "
                                       "(see its docstring; --report redraws)\n")


if __name__ == "__main__":
    main()
