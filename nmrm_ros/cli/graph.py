"""`nmrm demo`, `nmrm launch`, `nmrm fleet`: the graph of nodes, run."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import writable_dir


@app.command()
def demo(
    task: str = typer.Option("key", help="navigation task"),
    live_episodes: int = typer.Option(30, min=1, help="episodes collected with the live graph"),
    screened: int = typer.Option(1500, min=1, help="screened episodes generated in-process"),
    epochs: int = typer.Option(100, min=1, help="max training epochs"),
    agent_episodes: int = typer.Option(150, min=1, help="episodes of the DQN agent trained through the graph"),
    seed: int = typer.Option(0, min=0, help="seed of data, split, weights and agent"),
    out: Path = typer.Option(Path("runs/demo"), help="output directory (replaced)", callback=writable_dir),
) -> None:
    """The main job, end to end on a small task (nmrm_ros/demo.py): collect episodes with the live
    graph, generate screened ones, train a CSC LSTM reward model from the bags, serve it on a replay
    and compare with the oracle, then train a DQN agent through the graph on the served reward and
    judge its greedy policy by the oracle against a random policy."""
    from ..demo import DemoError, run_demo
    from ..tasks import NAVIGATION_TASKS, task_info

    if not task_info(task).navigation:
        raise typer.BadParameter(f"the demo runs a navigation task {NAVIGATION_TASKS}, not {task!r}")
    try:
        run_demo(task, live_episodes, screened, epochs, agent_episodes, seed, out, echo=typer.echo)
    except DemoError as exc:
        typer.echo(f"demo failed: {exc}", err=True)
        raise typer.Exit(1) from None


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def launch(
    ctx: typer.Context,
    file: Path = typer.Argument(..., help="a ROS 2 YAML launch file (see nmrm_ros/launcher.py)"),
    grace: float = typer.Option(10.0, min=0.0, help="seconds between SIGINT and SIGTERM when stopping"),
) -> None:
    """Run a launch file's nodes as separate processes; extra NAME:=VALUE set launch arguments."""
    from ..launcher import parse_launch_file, run

    arguments = {}
    for item in ctx.args:
        if ":=" not in item:
            raise typer.BadParameter(f"launch arguments are NAME:=VALUE, got {item!r}")
        name, value = item.split(":=", 1)
        arguments[name] = value
    nodes = parse_launch_file(file, arguments)
    raise typer.Exit(run(nodes, grace=grace))


@app.command()
def fleet(
    robots: int = typer.Option(2, min=1, help="number of robots (namespaces /robot1 ... /robotN)"),
    task: str = typer.Option("key", help="timer | moving | key | charger | lunar_lander"),
    episodes: int = typer.Option(100, min=1, help="episodes per robot (the learner learns from robots x episodes)"),
    mode: str = typer.Option("oracle", help="reward of every robot's reward_model: oracle | model"),
    checkpoint: Path = typer.Option(None, help="MIL checkpoint for mode model"),
    seed: int = typer.Option(0, min=0, help="agent seed; robot i's episodes start from seed + i * 100000"),
    out: Path = typer.Option(Path("runs/fleet"), help="output: OUT/policy (the learner) and OUT/bag (all robots)",
                             callback=writable_dir),
    save_every: int = typer.Option(50, min=1, help="save the policy every this many fleet episodes"),
    learning_starts: int = typer.Option(-1, min=-1, help="random steps before learning (-1: config/rl.yaml)"),
    save_replay_buffer: bool = typer.Option(False, help="also save OUT/policy/replay_buffer.pkl"),
    grace: float = typer.Option(10.0, min=0.0, help="seconds between SIGINT and SIGTERM when stopping"),
) -> None:
    """N namespaced robot graphs (env_sim, reward_model, labeller) and one learner that trains one
    policy from all of them, with one recorder for the fleet (launch_scripts/fleet_*.launch.yaml)."""
    from ..fleet import run_fleet
    from ..mil import load_checkpoint

    if mode not in ("oracle", "model"):
        raise typer.BadParameter(f"--mode must be oracle or model, got {mode!r}")
    if mode == "model":
        if checkpoint is None:
            raise typer.BadParameter("--mode model needs --checkpoint")
        load_checkpoint(checkpoint)
    code = run_fleet(robots, grace=grace, task=task, episodes=episodes, out=out, mode=mode,
                     checkpoint=checkpoint or "", seed=seed, save_every=save_every,
                     learning_starts=learning_starts, save_replay_buffer=save_replay_buffer)
    raise typer.Exit(code)


