"""`nmrm bag info|repair`: inspect and repair MCAP bags."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app


bag_app = typer.Typer(help="Inspect and repair MCAP bags.", no_args_is_help=True)
app.add_typer(bag_app, name="bag")


@bag_app.command("info")
def bag_info(path: Path = typer.Argument(..., help="bag directory or .mcap file")) -> None:
    """Topics, types and message counts of a bag, and its episodes."""
    from ..bags import BagError, bag_summary, iter_raw, load_bag_dataset

    summary = bag_summary(path)
    for topic, (type_name, count) in summary.items():
        typer.echo(f"{topic:28s} {type_name:34s} {count:8d}")
    sum(1 for _ in iter_raw(path))  # every chunk read and its CRC checked
    try:
        _, report = load_bag_dataset([path])
        typer.echo(f"episodes: {report}")
    except BagError as exc:
        typer.echo(f"episodes: {exc}")


@bag_app.command("repair")
def bag_repair(path: Path = typer.Argument(..., help="bag directory (or .mcap) of a killed recording")) -> None:
    """Rebuild a damaged or killed recording from every intact chunk (original kept beside it)."""
    from ..bags import BagError, load_bag_dataset, repair_bag

    report = repair_bag(path)
    typer.echo(f"repaired {report.path}: {report.messages} messages recovered "
               f"({', '.join(f'{t} {n}' for t, n in report.topics.items())}) from "
               f"{report.chunks_kept} intact chunk(s); lost: {report.chunks_lost} damaged chunk(s)"
               f"{f', {report.messages_without_channel} message(s) of unknown channels' if report.messages_without_channel else ''}; "
               f"damage: {report.damaged}; original kept as {report.backup}")
    try:
        _, episodes = load_bag_dataset([report.path])
        typer.echo(f"episodes: {episodes}")
    except BagError as exc:
        typer.echo(f"episodes: {exc}")


