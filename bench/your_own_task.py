"""The "your own task" example, measured: CartPole with a non-Markovian oracle of its own.

    .venv/bin/python bench/your_own_task.py models --repeats 5 --jobs 2
    .venv/bin/python bench/your_own_task.py agents --seeds 0 1 2 --jobs 2
    .venv/bin/python bench/your_own_task.py loop --seeds 0 1 2 3 4 --jobs 2
    .venv/bin/python bench/your_own_task.py --report
    # any task and oracle, results in bench/results/your_own_task/NAME/ (e.g. the fake robot's delivery):
    .venv/bin/python bench/your_own_task.py models --name delivery --repeats 3 \
        --task "nmrm_ros.robots.delivery:DeliveryEnv,max_steps=200,xy=0/1" --oracle nmrm_ros.robots.delivery:oracle
    # a paper task on data seeds no other bench uses, at the paper's 5000 episodes, with its own oracle and defaults:
    .venv/bin/python bench/your_own_task.py models --name charger_new --task charger --oracle '' \
        --episodes 5000 --first-data-seed 30 --repeats 3 --archs csc_lstm
    # agents with other RL settings than config/rl.yaml's, beside the default ones (results in agents_<settings>/):
    .venv/bin/python bench/your_own_task.py agents --rl-set learning_rate=1e-3 gamma=0.99 ...

Default task `gym:CartPole-v1,max_episode_steps=200`; oracle examples/cartpole_crossings.py:oracle (a
step pays 1 once the cart has crossed the centre line in both directions); --task/--oracle/--name
measure any other. Datasets are screened by
return bins from random-policy pools (nmrm_ros.datasets.return_screening); episodes vary in length.

models: repeat r trains the CSC LSTM and the Markovian Instance Space NN (the task's config, for a
user's task your_own_task: the mean of 3 models, member j weight seed r + 1000 j; `nmrm_ros.mil.fit`,
as `nmrm train`: the served member is the best on validation) on split r of a dataset of data seed
r (--first-data-seed F: F + r; --episodes episodes, default 2000),
scored on its test split and on a held-out dataset of data seed 999. Models trained before
2026-12-06 served member 0 (their checkpoints record it; they are not retrained).
agents: double DQN (config/rl.yaml, 400 episodes; --rl-set changes settings) on the repeat-0 CSC model's reward (served
state: the default; `--model-repeats 0 1 2`: on each of those repeats' models, i.e. data seeds, as issue 50's table asks), on the oracle's reward with its hidden state, and without it; agent seeds as
given; each judged by the oracle, greedy, on 50 episodes of seeds 10^8.. (`nmrm rl evaluate`).
loop: the documented repair, `nmrm loop --rounds R --labels-per-round L --seed s` (default 4 x 500:
round 0 labels L screened random episodes of data seed s, rounds 1.. the agent's own episodes; the
agent's seed is s too), judged as the agents: greedy oracle return of its kept policy.
Every agent and loop records whether it collapsed (`nmrm_ros.rl.collapse`: a late dip, or Q beyond
its bound); the report counts them among the runs that recorded it.

Resumes: every run is a JSON file in bench/results/your_own_task/ and is skipped when present,
unless a model's recorded training settings are not today's defaults or an agent's reward model
is not the one it learnt on (`nmrm_ros.resume`): then it runs again.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nmrm_ros.paper import mean_sem, mean_seconds
from nmrm_ros.mil.checkpoint import recorded_weights_sha256
from nmrm_ros.resume import stale_rl_settings, stale_settings

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "your_own_task"
DATA = ROOT / "runs" / "your_own_task"
TASK = "gym:CartPole-v1,max_episode_steps=200"
ORACLE = str(ROOT / "examples" / "cartpole_crossings.py") + ":oracle"

DEFAULT_EPISODES = 2000  # a repeat's dataset


@dataclass(frozen=True)
class Setting:
    """What is measured and where it goes (the CartPole example, or --task/--oracle/--name)."""
    task: str = TASK
    oracle: str = ORACLE
    name: str = ""  # results in RESULTS/NAME/, data in DATA/NAME/ ("": the CartPole example's own)
    rl_set: tuple = ()  # agents: (setting, value) pairs changing config/rl.yaml's
    episodes: int = DEFAULT_EPISODES  # models: episodes of each repeat's dataset
    first_data_seed: int = 0  # models: repeat r's dataset has data seed first_data_seed + r

    def data_seed(self, r: int) -> int:
        return self.first_data_seed + r

    @property
    def rl_tag(self) -> str:
        return ",".join(f"{k}={v}" for k, v in self.rl_set)

    @property
    def agent_results(self) -> Path:
        """Where the agents' JSON files go: the results directory, or agents_<settings>/ in it."""
        return self.results / f"agents_{self.rl_tag}" if self.rl_set else self.results

    @property
    def results(self) -> Path:
        return RESULTS / self.name if self.name else RESULTS

    @property
    def data(self) -> Path:
        return DATA / self.name if self.name else DATA
HELD_OUT_SEED, HELD_OUT_N = 999, 1000
ARCHS = ("csc_lstm", "instance_nn")
REWARDS = ("model", "oracle", "oracle-no-hidden")


def dataset(setting: Setting, n: int, seed: int):
    """The screened dataset of data seed `seed`, cached in the setting's data directory."""
    from nmrm_ros.datasets import TrajectoryDataset, generate_screened

    path = setting.data / f"{setting.name or 'cartpole'}_n{n}_s{seed}.npz"
    if path.is_file():
        return TrajectoryDataset.load(path)
    ds = generate_screened(setting.task, n, seed=seed, oracle=setting.oracle)
    setting.data.mkdir(parents=True, exist_ok=True)
    ds.save(path)
    return ds


def checkpoint_path(setting: Setting, arch: str, r: int) -> Path:
    return setting.data / "models" / f"{arch}_r{r}"


def run_model(job: tuple) -> dict:
    setting, arch, r = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.mil import evaluate, fit, load_train_config

    ds, held = dataset(setting, setting.episodes, setting.data_seed(r)), dataset(setting, HELD_OUT_N, HELD_OUT_SEED)
    cfg = load_train_config(setting.task, seed=r)
    # weight seeds r + 1000 j (cfg.seed = r), split r; seconds: CPU time of fit (the training and its
    # evaluation of each member, a few seconds; as wall time on 1 thread)
    t0 = time.process_time()
    run = fit(ds, arch, cfg, members=cfg.members, split_seed=r, offsets=[1000 * j for j in range(cfg.members)],
              progress=False)
    seconds = time.process_time() - t0
    result, seeds, on_test, on_held = run.train, run.meta.ensemble.seeds, run.meta.metrics["test"], evaluate(run.model, held)
    path = checkpoint_path(setting, arch, r)
    run.save(path)
    res = {"arch": arch, "repeat": r, "data_seed": setting.data_seed(r), "n": setting.episodes, "weight_seeds": seeds,
           "held_out_seed": HELD_OUT_SEED, "test_return_mse": on_test["return_mse"],
           "test_reward_mse": on_test["reward_mse"], "held_return_mse": on_held["return_mse"],
           "held_reward_mse": on_held["reward_mse"], "epochs": result.epochs_run,
           "best_epochs": result.best_epochs, "seconds": seconds, "clock": "cpu", "checkpoint": str(path),
           "config": cfg.to_dict()}
    (setting.results / f"model_{arch}_r{r}.json").write_text(json.dumps(res, indent=1))
    return res


def agent_name(reward: str, seed: int, repeat: int = 0) -> str:
    """agent_<reward>_s<seed>, or agent_model_r<repeat>_s<seed> on another repeat's model than 0."""
    return f"agent_{reward}_r{repeat}_s{seed}" if reward == "model" and repeat else f"agent_{reward}_s{seed}"


def run_agent(job: tuple) -> dict:
    setting, reward, seed, repeat = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl import evaluate_agent, train_agent

    checkpoint = checkpoint_path(setting, "csc_lstm", repeat) if reward == "model" else None
    out = setting.data / "agents" / (setting.rl_tag or ".") / agent_name(reward, seed, repeat)[len("agent_"):]
    t0 = time.perf_counter()
    run = train_agent(setting.task, reward, checkpoint=checkpoint, seed=seed, out=out, progress=False,
                      oracle=setting.oracle, **dict(setting.rl_set))
    seconds = time.perf_counter() - t0
    result = evaluate_agent(out / "policy.zip", setting.task, checkpoint=checkpoint, oracle=setting.oracle)
    res = {"reward": reward, "seed": seed, "model_repeat": repeat if reward == "model" else None, "checkpoint_sha256": recorded_weights_sha256(checkpoint) if checkpoint else None,
           "greedy_oracle_return": float(result.returns.mean()),
           "random_oracle_return": float(result.random_returns.mean()), "episodes": len(run.curve.records),
           "seconds": seconds, "late_dip": late_dip(out / "curve.csv"), "policy": str(out / "policy.zip"), "rl_config": json.loads((out / "agent.json").read_text())["config"],
           "collapsed": bool(run.collapse and run.collapse.collapsed), "collapse": run.collapse.summary() if run.collapse else "",
           "model_check": run.model_check.to_dict() if run.model_check else None}
    setting.agent_results.mkdir(parents=True, exist_ok=True)
    (setting.agent_results / f"{agent_name(reward, seed, repeat)}.json").write_text(json.dumps(res, indent=1))
    return res


def loop_name(seed: int, rounds: int, labels: int) -> str:
    return f"loop_{rounds}x{labels}_s{seed}"


def run_loop_job(job: tuple) -> dict:
    setting, seed, rounds, labels = job
    import torch

    torch.set_num_threads(1)
    from nmrm_ros.rl.reward_model_loop import run_loop

    out = setting.data / "loops" / loop_name(seed, rounds, labels)
    result = run_loop(setting.task, rounds, labels, seed=seed, out=out, oracle=setting.oracle, log=lambda *a: None)
    res = {"reward": "loop", "seed": seed, "rounds": rounds, "labels_per_round": labels,
           "greedy_oracle_return": result.greedy_oracle_return, "final_oracle_return": result.final_oracle_return,
           "round_oracle_returns": [r.mean_oracle_return for r in result.rounds],
           "round_val_return_mse": [r.training.get("val_return_mse") for r in result.rounds],
           "serving_members": [r.training.get("serving_member") for r in result.rounds],
           "seconds": result.seconds, "collapsed": result.collapsed, "collapse": result.collapse,
           "last_model_agrees": result.last_model_agrees, "last_model_check": result.last_model_check,
           "late_dip": late_dip(out / "agent" / "curve.csv"), "policy": str(out / "agent" / "policy.zip"),
           "rl_config": json.loads((out / "agent" / "agent.json").read_text())["config"]}
    (setting.results / f"{loop_name(seed, rounds, labels)}.json").write_text(json.dumps(res, indent=1))
    return res


def loop_done(setting: Setting, seed: int, rounds: int, labels: int) -> bool:
    """The loop of `seed` is finished with today's RL settings (its models train with the task's
    config of the day, as `nmrm loop`'s)."""
    path = setting.results / f"{loop_name(seed, rounds, labels)}.json"
    if not path.is_file():
        return False
    stale = stale_rl_settings(json.loads(path.read_text()).get("rl_config"), setting.task)
    if stale:
        print(f"# {path.name}: not today's RL settings ({'; '.join(stale)}): run again", flush=True)
    return not stale


def model_done(setting: Setting, arch: str, r: int) -> bool:
    """Repeat r of `arch` is finished with today's training settings (else it is run again)."""
    from nmrm_ros.mil import load_train_config

    path = setting.results / f"model_{arch}_r{r}.json"
    if not path.is_file():
        return False
    if not checkpoint_path(setting, arch, r).with_suffix(".pt").is_file():  # runs/ is not in git
        print(f"# {path.name}: its checkpoint is not on this machine: run again", flush=True)
        return False
    stale = stale_settings(json.loads(path.read_text()).get("config"), load_train_config(setting.task, seed=r))
    if stale:
        print(f"# {path.name}: not today's training settings ({'; '.join(stale)}): run again", flush=True)
    return not stale


def agent_done(setting: Setting, reward: str, seed: int, repeat: int = 0) -> bool:
    """The agent of (reward, seed) is finished with today's RL settings, and (reward model) learnt on
    today's model of that repeat."""
    path = setting.agent_results / f"{agent_name(reward, seed, repeat)}.json"
    if not path.is_file():
        return False
    res = json.loads(path.read_text())
    stale = stale_rl_settings(res.get("rl_config"), setting.task, **dict(setting.rl_set))
    if stale:
        print(f"# {path.name}: not today's RL settings ({'; '.join(stale)}): run again", flush=True)
        return False
    if reward != "model":
        return True
    return res.get("checkpoint_sha256") == recorded_weights_sha256(checkpoint_path(setting, "csc_lstm", repeat))


def late_dip(curve: Path) -> float:
    """The lowest mean oracle return of 50 consecutive training episodes in the run's second half
    (curve.csv; NaN when it is gone)."""
    import csv

    if not curve.is_file():
        return float("nan")
    with open(curve) as f:
        o = np.array([float(r["oracle_return"]) for r in csv.DictReader(f)])
    half = o[len(o) // 2:]
    if len(half) < 50:
        return float(half.mean()) if len(half) else float("nan")
    return float(np.convolve(half, np.ones(50) / 50, mode="valid").min())


def report(setting: Setting) -> str:
    oracle = ("examples/cartpole_crossings.py:oracle" if setting.oracle == ORACLE
              else setting.oracle or "the task's own")
    lines = [f"# bench/your_own_task.py: task {setting.task}, oracle {oracle}",
             f"# models: repeat r on data seed {setting.first_data_seed or ''}{' + ' if setting.first_data_seed else ''}r "
             f"({setting.episodes} episodes, split r); held-out: {HELD_OUT_N} episodes of "
             f"data seed {HELD_OUT_SEED}; mean ± SEM [worst]",
             f"{'model':12s} {'n':>2s} {'held-out return MSE':>26s} {'held-out reward MSE':>26s} "
             f"{'test return MSE':>24s} {'s/run':>6s}"]
    for arch in ARCHS:
        runs = [json.loads(p.read_text()) for p in sorted(setting.results.glob(f"model_{arch}_r*.json"))]
        if not runs:
            continue
        cells = []
        for key in ("held_return_mse", "held_reward_mse", "test_return_mse"):
            v = [r[key] for r in runs]
            m, s = mean_sem(v)
            cells.append(f"{m:9.4f} ± {s:7.4f} [{max(v):8.4f}]")
        lines.append(f"{arch:12s} {len(runs):2d} {' '.join(cells)} {mean_seconds(runs)}")
    lines.append("# agents: greedy oracle return over 50 episodes (seeds 10^8..); mean [worst] over agent seeds; late dip: "
                 "the lowest mean oracle return of 50 consecutive training episodes in the second half (a collapse shows there)")
    for where in [setting.results] + sorted(setting.results.glob("agents_*")):
        if where != setting.results:
            lines.append(f"# agents with config/rl.yaml's settings changed: {where.name[len('agents_'):]}")
        groups = [("model r0", "agent_model_s*.json")] + [
            (f"model r{r}", f"agent_model_r{r}_s*.json") for r in sorted(
                {int(p.name.split("_r")[1].split("_")[0]) for p in where.glob("agent_model_r*_s*.json")})] + [
            (w, f"agent_{w}_s*.json") for w in REWARDS[1:]]
        model_runs = []
        for label, pattern in groups:
            runs = [json.loads(p.read_text()) for p in sorted(where.glob(pattern))]
            if not runs:
                continue
            if label.startswith("model"):
                model_runs += runs
            v = [r["greedy_oracle_return"] for r in runs]
            # recorded with the run (runs/ is not in git); older runs: from their curve, if it is still there
            dips = [r.get("late_dip", late_dip(Path(r["policy"]).parent / "curve.csv")) for r in runs]
            lines.append(f"{label:18s} seeds {[r['seed'] for r in runs]}: {np.mean(v):7.2f} [{min(v):7.2f}] "
                         f"(random policy {np.mean([r['random_oracle_return'] for r in runs]):.2f}; "
                         f"{np.mean([r['seconds'] for r in runs]):.0f} s/run); late dip {np.mean(dips):7.2f} [{min(dips):7.2f}]"
                         f"{collapses(runs)}{replaced_model(setting, runs)}")
        oracle = [json.loads(p.read_text())["greedy_oracle_return"] for p in sorted(where.glob("agent_oracle_s*.json"))]
        if model_runs and oracle:
            lines.append(against_oracle("agents on the models of every data seed", model_runs, oracle))
        if where != setting.results:
            continue
        for budget in sorted({p.name.split("_")[1] for p in where.glob("loop_*_s*.json")}):
            runs = [json.loads(p.read_text()) for p in sorted(where.glob(f"loop_{budget}_s*.json"))]
            v = [r["greedy_oracle_return"] for r in runs]
            lines.append(f"{'loop ' + budget:18s} seeds {[r['seed'] for r in runs]}: {np.mean(v):7.2f} [{min(v):7.2f}] "
                         f"(last 50 training episodes {np.mean([r['final_oracle_return'] for r in runs]):.2f}; "
                         f"{np.mean([r['seconds'] for r in runs]):.0f} s/run){collapses(runs)}{switched_members(runs)}")
            if oracle:
                lines.append(against_oracle(f"the loop ({budget} labels, round 0 on data seed = agent seed)", runs, oracle))
    return "\n".join(lines)


def summary() -> str:
    """Issue 50's table: one row per measured task (the CartPole example and every NAME/ with a
    setting.json), agents with config/rl.yaml's settings only: the agents on the offline models of
    every data seed and the loop's kept policies, as fractions of the oracle-with-hidden agents'
    mean greedy oracle return (median, worst), with their collapses; a model's data seeds, the
    loop's labels and seconds."""
    names = [""] + sorted(p.parent.name for p in RESULTS.glob("*/setting.json"))
    lines = ["# bench/your_own_task.py --summary: greedy oracle return (50 episodes) as a fraction of the "
             "oracle-with-hidden agents' mean; median / worst [collapsed of known] <model check FAIL of known: the "
             "model against the oracle on the agent's last 50 episodes>; targets 90% / 80%, 0 collapses",
             f"{'name':18s} {'oracle agents':>15s} {'data seeds':>10s} {'agents on offline models':>26s} "
             f"{'the loop (labels, s/run)':>40s}"]
    for name in names:
        known = recorded_setting(name)
        setting = Setting(known["task"], known["oracle"], name, episodes=known["episodes"],
                          first_data_seed=known["first_data_seed"])
        where = setting.results
        oracle = [json.loads(p.read_text())["greedy_oracle_return"] for p in sorted(where.glob("agent_oracle_s*.json"))]
        if not oracle:
            continue
        ref = float(np.mean(oracle))
        offline = [json.loads(p.read_text()) for p in sorted(where.glob("agent_model_*s*.json"))]
        repeats = sorted({r.get("model_repeat") or 0 for r in offline})
        seeds = ",".join(str(setting.data_seed(r)) for r in repeats) or "-"

        def cell(runs: list[dict]) -> str:
            if not runs:
                return "-"
            v = np.array([r["greedy_oracle_return"] for r in runs]) / ref
            known_collapse = [c for c in map(collapsed, runs) if c is not None]
            c = f"{sum(known_collapse)}/{len(known_collapse)}" if known_collapse else "?"
            checked = [f for f in map(model_failed, runs) if f is not None]
            m = f"{sum(checked)}/{len(checked)}" if checked else "?"
            return f"n {len(v)}: {np.median(v):4.0%} / {v.min():4.0%} [{c}] <{m}>"

        loops = [json.loads(p.read_text()) for p in sorted(where.glob("loop_*_s*.json"))]
        budget = "".join(sorted({p.name.split("_")[1] for p in where.glob("loop_*_s*.json")}))
        loop = (f"{cell(loops)} ({budget}, {np.mean([r['seconds'] for r in loops]):.0f} s)" if loops else "-")
        old_rule = before_kept_member(loops)
        loop += f" ({old_rule} before the kept member)" if old_rule else ""
        lines.append(f"{name or 'cartpole':18s} {ref:7.2f} (n {len(oracle)}) {seeds:>10s} {cell(offline):>26s} {loop:>40s}")
    return "\n".join(lines)


def member_switching(loop: dict) -> bool:
    """Whether a loop ran before its retrains kept the served member (2026-12-07,
    nmrm_ros.mil.retrain): neither it nor its loop.json (if still on this machine) records which
    member each round's model served."""
    if "serving_members" in loop:
        return False
    loop_json = Path(loop["policy"]).parent.parent / "loop.json"
    rounds = json.loads(loop_json.read_text()).get("rounds", []) if loop_json.is_file() else []
    return not rounds or any("serving_member" not in r.get("training", {}) for r in rounds)


def before_kept_member(loops: list[dict]) -> int:
    """How many of `loops` ran when a retrain could switch the served member."""
    return sum(map(member_switching, loops))


def switched_members(loops: list[dict]) -> str:
    """'; k of n before the kept member' for loops run when a retrain could switch the served member."""
    old = before_kept_member(loops)
    return f"; {old} of {len(loops)} before the kept member (docs/guide/loop.md)" if old else ""


def replaced_model(setting: Setting, runs: list[dict]) -> str:
    """'; on a replaced model' when some agents learnt on a checkpoint of their model repeat that has
    since been trained again (its weights differ from the one on this machine); '' otherwise,
    also when that repeat's checkpoint is not on this machine (nothing to compare with)."""
    repeats = {r["model_repeat"] for r in runs if r.get("model_repeat") is not None}
    if len(repeats) != 1:
        return ""
    checkpoint = checkpoint_path(setting, "csc_lstm", repeats.pop())
    if not checkpoint.with_suffix(".pt").is_file():
        return ""
    today = recorded_weights_sha256(checkpoint)
    old = sum(r.get("checkpoint_sha256") != today for r in runs)
    return f"; {old} of {len(runs)} on a replaced model (retrained since)" if old else ""


def model_failed(run: dict) -> bool | None:
    """Whether the model failed its check where the agent went (`nmrm_ros.rl.model_check`): an
    agent's model (its recorded `model_check`, or, for runs before 2026-12-07, replayed from its
    curve.csv and checkpoint if still on this machine), a loop's last model (`last_model_agrees`,
    or replayed from its loop.json, labels.npz and curve.csv); None: unknown or not made."""
    from nmrm_ros.rl.model_check import model_check_of_run
    from nmrm_ros.rl.reward_model_loop import last_model_check

    run_dir = Path(run["policy"]).parent
    if run.get("reward") == "loop":
        if run.get("last_model_agrees") is not None:
            return not run["last_model_agrees"]
        loop_json, labels = run_dir.parent / "loop.json", run_dir.parent / "labels.npz"
        if not (loop_json.is_file() and labels.is_file() and (run_dir / "curve.csv").is_file()):
            return None
        from nmrm_ros.datasets import TrajectoryDataset

        loop = json.loads(loop_json.read_text())
        last = loop["rounds"][-1]
        curve = read_curve(run_dir / "curve.csv")[last["first_episode"]:last["last_episode"]]
        first = TrajectoryDataset.load(labels).returns[:loop["labels_per_round"]]
        check = last_model_check([r[1] for r in curve], [r[0] for r in curve], last["index"],
                                 float(last["training"]["val_return_mse"]), first)
        return not check.passed
    if "model_check" in run:
        return None if run["model_check"] is None else not run["model_check"]["passed"]
    agent = run_dir / "agent.json"
    if run.get("reward") != "model" or not agent.is_file() or not (run_dir / "curve.csv").is_file():
        return None
    curve = read_curve(run_dir / "curve.csv")
    check = model_check_of_run(json.loads(agent.read_text())["checkpoint"], [r[1] for r in curve],
                               [r[0] for r in curve])
    return None if check is None else not check.passed


def read_curve(path: Path) -> list:
    """curve.csv's rows as (oracle return, learnt return)."""
    import csv

    with open(path) as f:
        return [(float(r["oracle_return"]), float(r["learnt_return"])) for r in csv.DictReader(f)]


def collapsed(run: dict) -> bool | None:
    """Whether an agent or loop run collapsed: as it recorded, or (runs before 2026-12-07) as its
    agent.json beside the policy says, if that is still on this machine; None: unknown."""
    if "collapsed" in run:
        return bool(run["collapsed"])
    agent = Path(run["policy"]).parent / "agent.json"
    if agent.is_file():
        report = json.loads(agent.read_text()).get("collapse")
        return None if report is None else bool(report["collapsed"])
    return None


def collapses(runs: list[dict]) -> str:
    """'; collapsed k of n' over the runs whose collapse is known ('' if none)."""
    known = [c for c in map(collapsed, runs) if c is not None]
    return f"; collapsed {sum(known)} of {len(known)}" if known else ""


def against_oracle(what: str, runs: list[dict], oracle: list[float]) -> str:
    v = np.array([r["greedy_oracle_return"] for r in runs]) / np.mean(oracle)
    return (f"# issue 50: {what} ({len(v)} runs) / the oracle-with-hidden agents' mean {np.mean(oracle):.2f}: "
            f"median {np.median(v):.0%}, worst {v.min():.0%} (targets 90% / 80%)")


def rl_settings(items: list[str]) -> tuple:
    """--rl-set's "name=value" items as sorted (name, value) pairs, values as YAML reads them; a
    setting config/rl.yaml does not have is an error."""
    import yaml

    from nmrm_ros.rl import load_rl_config

    pairs = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise SystemExit(f"--rl-set takes SETTING=VALUE, got {item!r}")
        value = yaml.safe_load(value)
        try:
            value = float(value) if isinstance(value, str) else value  # YAML reads 1e-3 as a string
        except ValueError:
            raise SystemExit(f"--rl-set {name}: {value!r} is not a number") from None
        pairs[name] = value
    try:
        load_rl_config("dqn", **pairs)
    except ValueError as exc:
        raise SystemExit(f"--rl-set: {exc}") from None
    return tuple(sorted(pairs.items()))


def recorded_setting(name: str) -> dict:
    """NAME/setting.json's task, oracle, episodes and first_data_seed, the defaults where it has
    none (the CartPole example's for name '')."""
    known = json.loads((RESULTS / name / "setting.json").read_text()) if name else {"task": TASK, "oracle": ORACLE}
    return {"episodes": DEFAULT_EPISODES, "first_data_seed": 0, **known}


def named_task(name: str, task: str, oracle: str, episodes: int | None = None,
               first_data_seed: int | None = None) -> tuple[str, str, int, int]:
    """The task, oracle, episodes per dataset and first data seed of the results NAME/: recorded in
    NAME/setting.json by its first run (episodes 2000 and data seed 0 when not given); later runs (and
    --report) may leave them out, but not give others."""
    if not name:
        return task, oracle, episodes or DEFAULT_EPISODES, first_data_seed or 0
    record = RESULTS / name / "setting.json"
    if not record.is_file():
        if (task, oracle) == (TASK, ORACLE):
            raise SystemExit(f"--name {name}: no results yet; give its --task and --oracle")
        record.parent.mkdir(parents=True, exist_ok=True)
        known = {"task": task, "oracle": oracle}
        known.update({k: v for k, v in (("episodes", episodes), ("first_data_seed", first_data_seed)) if v is not None})
        record.write_text(json.dumps(known, indent=1))
        return task, oracle, episodes or DEFAULT_EPISODES, first_data_seed or 0
    known = recorded_setting(name)
    if (task, oracle) != (TASK, ORACLE) and (task, oracle) != (known["task"], known["oracle"]):
        raise SystemExit(f"--name {name} holds task {known['task']} with oracle {known['oracle']!r}, "
                         f"not {task} with {oracle!r}: give another --name")
    for key, given in (("episodes", episodes), ("first_data_seed", first_data_seed)):
        if given is not None and given != known[key]:
            raise SystemExit(f"--name {name} holds {key.replace('_', '-')} {known[key]}, not {given}: give another --name")
    return known["task"], known["oracle"], known["episodes"], known["first_data_seed"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", nargs="?", choices=("models", "agents", "loop"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--archs", nargs="*", default=list(ARCHS), choices=ARCHS, help="models: which architectures")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--rewards", nargs="*", default=list(REWARDS), choices=REWARDS, help="agents: which rewards")
    parser.add_argument("--model-repeats", type=int, nargs="*", default=[0],
                        help="agents: on the CSC models of these repeats (data seeds; default 0)")
    parser.add_argument("--rounds", type=int, default=4, help="loop: rounds")
    parser.add_argument("--labels-per-round", type=int, default=500, help="loop: labels per round")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--report", action="store_true")
    parser.add_argument("--summary", action="store_true",
                        help="issue 50's table over every task measured (summary.txt), then stop")
    parser.add_argument("--task", default=TASK, help="task spec (default: the CartPole example)")
    parser.add_argument("--oracle", default=ORACLE, help="oracle <module>:<function> or <file.py>:<function>; "
                        "'' for a task's own (e.g. --task charger --oracle '')")
    parser.add_argument("--episodes", type=int, default=None,
                        help=f"models: episodes per dataset (default {DEFAULT_EPISODES}; recorded for --name)")
    parser.add_argument("--first-data-seed", type=int, default=None,
                        help="models: repeat r's dataset has data seed FIRST + r (default 0; recorded for --name), "
                             "e.g. data seeds no other bench uses")
    parser.add_argument("--name", default="", help="results in bench/results/your_own_task/NAME/ (needed with --task)")
    parser.add_argument("--rl-set", nargs="*", default=[], metavar="SETTING=VALUE",
                        help="agents: change config/rl.yaml's settings (e.g. learning_rate=1e-3); results in agents_<settings>/")
    args = parser.parse_args()
    if (args.task, args.oracle) != (TASK, ORACLE) and not args.name:
        raise SystemExit("give --name for another task or oracle (its results go to bench/results/your_own_task/NAME/)")
    if args.summary:
        text = summary()
        print(text)
        (RESULTS / "summary.txt").write_text(text + "\n")
        return
    if (args.episodes is not None or args.first_data_seed is not None) and not args.name:
        raise SystemExit("--episodes and --first-data-seed need --name (the CartPole example's results are 2000 "
                         "episodes from data seed 0)")
    if args.episodes is not None and args.episodes < 10:
        raise SystemExit(f"--episodes must be at least 10, got {args.episodes}")
    if args.first_data_seed is not None and not 0 <= args.first_data_seed < 2**31 - 1000:
        raise SystemExit(f"--first-data-seed must be a seed >= 0, got {args.first_data_seed}")
    task, oracle, episodes, first = named_task(args.name, args.task, args.oracle, args.episodes, args.first_data_seed)
    setting = Setting(task, oracle, args.name, rl_settings(args.rl_set), episodes, first)
    results = setting.results
    results.mkdir(parents=True, exist_ok=True)
    if args.what == "models":
        dataset(setting, HELD_OUT_N, HELD_OUT_SEED)
        jobs = [(setting, a, r) for r in range(args.repeats) for a in args.archs if not model_done(setting, a, r)]
        fn = run_model
    elif args.what == "agents":
        missing = [r for r in args.model_repeats if not (results / f"model_csc_lstm_r{r}.json").is_file()
                   or not checkpoint_path(setting, "csc_lstm", r).with_suffix(".pt").is_file()]
        if missing:
            raise SystemExit(f"train the models first (repeats {missing}): bench/your_own_task.py models")
        jobs = [(setting, w, s, r) for r in args.model_repeats for s in args.seeds for w in args.rewards
                if (w == "model" or r == args.model_repeats[0]) and not agent_done(setting, w, s, r)]
        fn = run_agent
    elif args.what == "loop":
        from nmrm_ros.rl.reward_model_loop import check_loop_arguments

        try:
            check_loop_arguments(args.rounds, args.labels_per_round, None, "returns")
        except ValueError as exc:
            raise SystemExit(f"loop: {exc}") from None
        jobs = [(setting, s, args.rounds, args.labels_per_round) for s in args.seeds
                if not loop_done(setting, s, args.rounds, args.labels_per_round)]
        fn = run_loop_job
    else:
        jobs, fn = [], None
    if jobs:
        print(f"# {len(jobs)} runs (finished ones skipped)", flush=True)
        with ProcessPoolExecutor(args.jobs) as pool:
            for res in pool.map(fn, jobs):
                print(f"  {json.dumps({k: v for k, v in res.items() if not isinstance(v, (list, dict))})}", flush=True)
    text = report(setting)
    print(text)
    (results / "table.txt").write_text(text + "\n")


if __name__ == "__main__":
    main()
