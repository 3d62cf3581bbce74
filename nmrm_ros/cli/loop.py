"""`nmrm loop`: the reward-model loop (agent, labels, retraining) in one command."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import (TASK_HELP, ORACLE_HELP, BETA_OPT, MISTAKE_OPT, EQUAL_OPT, GAMMA_OPT, SKIP_OPT,
                     writable_dir, check_teacher)


@app.command("loop")
def loop_command(
    task: str = typer.Option(..., help=TASK_HELP),
    rounds: int = typer.Option(4, min=1, help="rounds of labelling, model training and RL (1: the offline baseline)"),
    labels_per_round: int = typer.Option(250, min=10, help="episodes labelled per round (round 0: screened "
                                                            "random episodes; then the agent's)"),
    episodes: int = typer.Option(None, min=1, help="the agent's training episodes over all rounds "
                                                  "(default: config/rl.yaml, 400 DQN / 800 SAC)"),
    seed: int = typer.Option(0, min=0, help="seed of the agent, its episodes, round 0's data and the models"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; it labels and judges every episode"),
    members: int = typer.Option(None, min=1, help="models per reward model (default: the task's training config)"),
    max_epochs: int = typer.Option(None, min=1, help="epoch limit of each training (default: the task's config)"),
    out: Path = typer.Option(Path("runs/loop"), help="output directory: labels.npz, model_<round>, agent/, loop.json",
                             callback=writable_dir),
    feedback: str = typer.Option("returns", help="what the oracle gives: returns (one per episode) | preferences "
                                                 "(a simulated teacher's comparisons, --labels-per-round of them "
                                                 "a round, each new episode against earlier ones) | both"),
    beta: float = BETA_OPT, mistake: float = MISTAKE_OPT, equal: float = EQUAL_OPT, gamma: float = GAMMA_OPT,
    skip: float = SKIP_OPT,
) -> None:
    """The reward-model <-> agent loop: each round labels episodes (the oracle's returns, or a
    simulated teacher's comparisons), retrains the MIL model on all labels so far (warm start) and
    lets the agent learn on it; the agent's replay buffer is relabelled with each new model."""
    from ..datasets.preference_teacher import SimulatedTeacher
    from ..rl.reward_model_loop import check_loop_arguments, run_loop
    from ..tasks import check_task

    check_task(task)
    check_loop_arguments(rounds, labels_per_round, episodes, feedback)
    check_teacher(feedback, None, beta, mistake, equal, gamma, skip)
    teacher = SimulatedTeacher(beta=beta, mistake=mistake, equal=equal, gamma=gamma, skip=skip)
    result = run_loop(task, rounds, labels_per_round, episodes=episodes, seed=seed, out=out, oracle=oracle,
                      members=members, max_epochs=max_epochs, log=typer.echo, feedback=feedback,
                      teacher=teacher)
    typer.echo(result.summary())
    typer.echo(f"wrote {out}/loop.json, labels.npz, model_*.pt, agent/")


