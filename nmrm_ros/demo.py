"""The main job (`nmrm demo`, `bash scripts/main.sh`): the whole pipeline on one small task.

1. the live graph (env_sim, a random agent, labeller_oracle, recorder) collects labelled episodes
   into a bag (`OUT/live`);
2. screened episodes are generated in-process into a second bag (`OUT/screened`; random-policy
   episodes rarely reach the Key task's rewards, screening balances the dataset);
3. a CSC Instance Space LSTM is trained from those bags plus the task's sample bag in bags/
   (episodes that occur twice in the data, by content, are used once);
4. the reward_model node serves it on a replay of the live bag; a recorder records what it
   publishes (`OUT/served`) and the served rewards are compared with the oracle's ground truth;
5. a double-DQN agent learns through the graph on the served reward and hidden state
   (learn.launch.yaml: env_sim -> reward_model -> agent policy:=learn, labeller, recorder;
   `OUT/learn`), and its greedy policy is judged by the oracle beside a random policy.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Callable

import numpy as np


class DemoError(RuntimeError):
    """A step of the demo failed (a node exited non-zero, a bag could not be read)."""


def repo_dir(name: str) -> Path | None:
    """A top-level folder of the source tree (the working directory's, or this file's), if any."""
    for base in (Path.cwd(), Path(__file__).resolve().parents[1]):
        if (base / name).is_dir() and (base / "package.xml").is_file():
            return base / name
    return None


def launch_dir() -> Path:
    """launch_scripts/ of the source tree, else of the installed share directory."""
    here = repo_dir("launch_scripts")
    if here is not None:
        return here
    from .ros.ament_paths import require_share_dir

    return require_share_dir("nmrm_ros") / "launch_scripts"


def _launch(name: str, arguments: dict) -> None:
    from .launcher import parse_launch_file, run

    code = run(parse_launch_file(launch_dir() / name, {k: str(v) for k, v in arguments.items()}))
    if code != 0:
        raise DemoError(f"{name} exited with code {code}")


def run_demo(task: str, live_episodes: int, screened: int, epochs: int, agent_episodes: int,
             seed: int, out: Path, echo: Callable[[str], None] = print) -> dict:
    """Run the five steps (module docstring); returns the headline figures."""
    from .bags import BagError, iter_decoded, load_bag_dataset, write_dataset_bag
    from .datasets import generate_screened
    from .mil import evaluate as evaluate_model, load_train_config
    from .mil import DataSource
    from .mil.pipeline import fit
    from .rl import evaluate_agent

    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    live, gen, served, ckpt, learn = out / "live", out / "screened", out / "served", out / "csc", out / "learn"
    t0 = time.perf_counter()
    figures: dict = {}

    echo(f"[1/5] live graph: {live_episodes} {task} episodes -> {live}")
    _launch("collect.launch.yaml", {"task": task, "episodes": live_episodes, "seed": seed, "out": live})

    echo(f"[2/5] screened episodes: {screened} -> {gen}")
    write_dataset_bag(generate_screened(task, screened, seed=seed), gen, first_episode=10**6)

    bags_dir = repo_dir("bags")
    sample = bags_dir / f"{task}_screened" if bags_dir else None
    sources = [live, gen] + ([sample] if sample is not None and sample.is_dir() else [])
    echo(f"[3/5] training csc_lstm from {' + '.join(map(str, sources))}")
    try:
        ds, report = load_bag_dataset(sources)
    except BagError as exc:
        raise DemoError(str(exc)) from None
    ds, duplicates = ds.deduplicated()
    echo(f"      {report}; {duplicates} duplicate episode(s) (same states and label) used once")
    cfg = load_train_config(task, max_epochs=epochs, seed=seed)
    run = fit(ds, "csc_lstm", cfg, split_seed=seed, out=ckpt, data_source=DataSource.bags(sources))
    m = run.test_metrics
    figures.update(test_return_mse=m["return_mse"], test_reward_mse=m["reward_mse"])
    echo(f"      best epoch {run.train.best_epochs[0]}, {run.train.seconds:.1f} s; test return MSE "
         f"{m['return_mse']:.4f} (label variance {ds.returns.var():.3f}), reward MSE "
         f"{m['reward_mse']:.5f}; checkpoint {run.checkpoint}")

    echo(f"[4/5] reward_model node on a replay of {live} -> {served}")
    _launch("serve_replay.launch.yaml", {"bag": live, "checkpoint": run.checkpoint, "out": served})
    try:
        served_rewards = {(int(msg.episode), int(msg.step)): float(msg.reward)
                          for _, t, _, msg in iter_decoded(served) if t.endswith("RewardStep")}
        truth, _ = load_bag_dataset([live])
    except BagError as exc:
        raise DemoError(str(exc)) from None
    errors = []
    for i, e in enumerate(truth.meta["episodes"]):
        length = int(truth.lengths[i])
        r = np.array([served_rewards[(e, t)] for t in range(length)])
        errors.append((r - truth.rewards[i, :length]) ** 2)
    err = float(np.concatenate(errors).mean())
    live_eval = evaluate_model(run.model, truth)
    figures["served_reward_mse"] = err
    echo(f"      {len(served_rewards)} rewards served for {len(errors)} episodes; served reward MSE vs "
         f"oracle {err:.5f} (offline model on the same episodes: {live_eval['reward_mse']:.5f})")

    echo(f"[5/5] DQN agent learning through the graph on the served reward: {agent_episodes} episodes -> {learn}")
    t_learn = time.perf_counter()
    _launch("learn.launch.yaml", {"task": task, "episodes": agent_episodes, "seed": seed, "mode": "model",
                                  "checkpoint": run.checkpoint, "out": learn, "save_every": 0})
    learn_seconds = time.perf_counter() - t_learn
    result = evaluate_agent(learn / "policy" / "policy.zip", task, checkpoint=run.checkpoint, episodes=100)
    figures.update(agent_oracle_return=float(result.returns.mean()),
                   random_oracle_return=float(result.random_returns.mean()), agent_seconds=learn_seconds)
    echo(f"      {agent_episodes} episodes in {learn_seconds:.0f} s; greedy policy on 100 new episodes: "
         f"{result.summary()}")
    echo(f"done in {time.perf_counter() - t0:.0f} s; outputs in {out}/ "
         f"(learning curve: {learn}/policy/curve.png)")
    return figures
