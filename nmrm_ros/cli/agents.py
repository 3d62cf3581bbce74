"""`nmrm rl train|evaluate`: RL agents on learnt or oracle rewards."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import TASK_HELP, ORACLE_HELP, writable_dir


rl_app = typer.Typer(help="Train and evaluate RL agents on learnt or oracle non-Markovian rewards.",
                     no_args_is_help=True)
app.add_typer(rl_app, name="rl")


@rl_app.command("train")
def rl_train(
    task: str = typer.Option(..., help=TASK_HELP),
    reward: str = typer.Option("model", help="model | oracle | oracle-no-hidden"),
    oracle: str = typer.Option("", help=ORACLE_HELP + "; it judges every episode"),
    checkpoint: Path = typer.Option(None, help="MIL checkpoint (reward model), trained on TASK"),
    episodes: int = typer.Option(None, min=1, help="training episodes (default: config/rl.yaml, 400 DQN / 800 SAC)"),
    seed: int = typer.Option(0, min=0, help="seed of the agent (weights, exploration) and of the episodes"),
    envs: int = typer.Option(1, min=1, help="environments stepped together (SB3 DummyVecEnv)"),
    out: Path = typer.Option(Path("runs/agent"), help="output directory: policy.zip, curve.csv, curve.png",
                             callback=writable_dir),
    observe: str = typer.Option("state", help="what the agent sees beside the served state: state (the "
                                "task's, e.g. a camera image) | privileged (the task's privileged state)"),
    config: Path = typer.Option(None, help="RL config YAML (default config/rl.yaml)", exists=True,
                                dir_okay=False, readable=True),
) -> None:
    """Train the paper's agent (double DQN, or SAC for Lunar Lander) on a non-Markovian reward;
    every episode is judged by the oracle (curve.csv)."""
    from ..rl import REWARD_KINDS, train_agent
    from ..rl.wrappers import OBSERVE
    from ..tasks import check_task, task_info

    check_task(task)
    if reward not in REWARD_KINDS:
        raise typer.BadParameter(f"unknown reward kind {reward!r}; use one of {', '.join(REWARD_KINDS)}")
    if reward == "model" and checkpoint is None:
        raise typer.BadParameter("--reward model needs --checkpoint (or use --reward oracle)")
    if episodes is not None and episodes < 1:
        raise typer.BadParameter(f"--episodes must be at least 1, got {episodes}")
    if observe not in OBSERVE:
        raise typer.BadParameter(f"unknown --observe {observe!r}; use one of {', '.join(OBSERVE)}")
    if observe == "privileged" and not task_info(task).privileged_size:
        raise typer.BadParameter(f"--observe privileged: task {task} has no privileged state")
    run = train_agent(task, reward, checkpoint=checkpoint, episodes=episodes, seed=seed, out=out,
                      n_envs=envs, config=config, oracle=oracle, observe=observe)
    steps = sum(r.steps for r in run.curve.records)
    typer.echo(f"{len(run.curve.records)} episodes, {steps} steps in {run.seconds:.0f} s "
               f"({steps / max(run.seconds, 1e-9):.0f} steps/s); oracle return of the last 50 episodes "
               f"{run.curve.final_oracle_return():.3f}")
    typer.echo(f"wrote {out}/policy.zip, curve.csv, curve.png")
    typer.echo(run.collapse.summary())
    if run.model_check is not None:
        from ..rl.acceptance import next_step

        typer.echo(run.model_check.summary())
        if not run.model_check.passed:
            typer.echo(next_step([run.model_check], str(checkpoint), task, oracle))


@rl_app.command("evaluate")
def rl_evaluate(
    policy: Path = typer.Option(..., help="policy.zip from `nmrm rl train` or the agent node"),
    task: str = typer.Option(..., help="the task the policy was trained on"),
    checkpoint: Path = typer.Option(None, help="the reward model it was trained with (default: agent.json)"),
    oracle: str = typer.Option(None, help="your own oracle that judges (default: agent.json's, else the task's)"),
    episodes: int = typer.Option(50, min=1, help="evaluation episodes"),
    seed: int = typer.Option(10**8, min=0, help="seed of the first evaluation episode"),
) -> None:
    """Mean oracle return (± SEM) of the greedy policy, and of a random policy on the same episodes."""
    from ..rl import evaluate_agent
    from ..tasks import check_task

    check_task(task)
    result = evaluate_agent(policy, task, checkpoint=checkpoint, episodes=episodes, seed=seed,
                            oracle=oracle)
    typer.echo(f"{task}, reward {result.reward}: {result.summary()}")


