"""`nmrm export lerobot` and `nmrm import lerobot`: LeRobot v3.0 datasets out of and into bags."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import TASK_HELP, writable_dir

export_app = typer.Typer(help="Write bags in another format.", no_args_is_help=True)
import_app = typer.Typer(help="Read another format into a bag.", no_args_is_help=True)
app.add_typer(export_app, name="export")
app.add_typer(import_app, name="import")


@export_app.command("lerobot")
def export_lerobot(
    bag: list[Path] = typer.Option(..., "--bag", help="a recording or labels bag (repeat: --bag B --bag LABELS)"),
    out: Path = typer.Option(..., callback=writable_dir, help="the new dataset directory (must not exist)"),
    checkpoint: Path | None = typer.Option(None, help="a reward model of the task: its r'_t as next.reward "
                                                      "and its served state as observation.reward_model_state"),
    task: str | None = typer.Option(None, help=f"the task to export where the bags hold several ({TASK_HELP})"),
    fps: int | None = typer.Option(None, min=1, help="frames per second (default: the recording's step rate)"),
    codec: str = typer.Option("h264", help="the camera's video codec: h264 | av1"),
    progress: bool = typer.Option(True, help="show a progress bar"),
) -> None:
    """Write episodes, rendered frames, labels, comparisons and (with --checkpoint) the learnt
    rewards as a LeRobot v3.0 dataset on disk (docs/guide/lerobot.md)."""
    from ..lerobot import export_lerobot as run

    typer.echo(str(run(bag, out, checkpoint=checkpoint, task=task, fps=fps, codec=codec, progress=progress)))


@import_app.command("lerobot")
def import_lerobot(
    dataset: Path = typer.Argument(..., help="a LeRobot v3.0 dataset directory (the one holding meta/info.json)"),
    out: Path = typer.Option(..., callback=writable_dir, help="the new bag directory (must not exist)"),
    task: str | None = typer.Option(None, help="a task spec whose state size is the state feature's, for "
                                               "episodes of an environment you have (default: the task the "
                                               "dataset was exported with, else the dataset itself, "
                                               "lerobot:<DATASET>: no environment)"),
    state: str = typer.Option("observation.state", help="the state feature"),
    action: str = typer.Option("action", help="the action feature ('' for none)"),
    camera: str | None = typer.Option(None, help="the video or image feature played on the labelling page "
                                                 "(default: the dataset's first; '' for none)"),
    episodes: str | None = typer.Option(None, help="which episodes, e.g. 0:100,150 (default: all)"),
    label: str | None = typer.Option(None, help="label each episode with the sum of this feature "
                                                "(e.g. next.reward)"),
) -> None:
    """Turn a LeRobot v3.0 dataset into a bag of episodes that the labelling page plays and
    `nmrm train` trains on (docs/guide/lerobot.md)."""
    from ..lerobot import import_lerobot as run

    typer.echo(str(run(dataset, out, task=task, state_key=state, action_key=action or None, camera=camera,
                       episodes=episodes, label_key=label)))
