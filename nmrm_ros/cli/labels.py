"""`nmrm labels report|export|import`: who gave which label."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from .app import app
from .common import writable_dir, writable_file


labels_app = typer.Typer(help="Labels: who gave which, how far people agree, export and import.",
                         no_args_is_help=True)
app.add_typer(labels_app, name="labels")


def _label_records(bag: list | None, checkpoint: Path | None, file: Path | None) -> list:
    """Label records from exactly one kind of source (bags, a checkpoint's provenance, a file)."""
    from ..labelling.label_files import checkpoint_labels, read_bag_labels, read_labels

    given = [x for x in (bag, checkpoint, file) if x]
    if len(given) != 1:
        raise typer.BadParameter("give labels bags (--bag), a checkpoint (--checkpoint) or a file (--file)")
    if bag:
        return read_bag_labels(bag)
    if checkpoint:
        return checkpoint_labels(checkpoint)
    return read_labels(file)


def _optional_labels(checkpoint: Path) -> list:
    """A checkpoint's return labels, or [] if it was trained on comparisons only."""
    from ..labelling.label_files import checkpoint_labels

    try:
        return [r for r in checkpoint_labels(checkpoint) if r.get("return") is not None]
    except ValueError:
        return []


@labels_app.command("report")
def labels_report(
    bag: list[Path] = typer.Option(None, help="labels bags or recordings (repeat for several)"),
    checkpoint: Path = typer.Option(None, help="a checkpoint: the labels it was built from"),
    file: Path = typer.Option(None, help="a labels file (.jsonl or .csv)"),
    show: bool = typer.Option(False, help="also list every label (latest per labeller and episode)"),
) -> None:
    """Who labelled how much, each person's error on gold episodes (labels of gold/ or oracle/
    labellers), and how far people agree on the episodes they both labelled; the same for
    comparisons (TrajectoryPreference) in bags and checkpoints."""
    from ..labelling.agreement import comparison_report, format_comparison_report, format_report, label_report
    from ..labelling.label_files import checkpoint_comparisons, latest, read_bag_comparisons

    comparisons = read_bag_comparisons(bag) if bag else checkpoint_comparisons(checkpoint) if checkpoint else []
    records = _label_records(bag, checkpoint, file) if not (comparisons and checkpoint) else \
        _optional_labels(checkpoint)
    if not records and not comparisons:
        raise typer.BadParameter("no labels there")
    if records:
        for line in format_report(label_report(records)):
            typer.echo(line)
    if comparisons:
        for line in format_comparison_report(comparison_report(comparisons)):
            typer.echo(line)
    if show:
        typer.echo(f"{'labeller':24s} {'source':10s} {'episode':>8s} {'length':>6s} {'return':>10s}  given (UTC)")
        for r in sorted(latest(records), key=lambda r: (r["source"], r["episode"], r["labeller"])):
            when = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(r["stamp_ns"] / 1e9))
            typer.echo(f"{r['labeller']:24s} {r['source'] or '-':10s} {r['episode']:8d} {r['length']:6d} "
                       f"{r['return']:10.4g}  {when}")


@labels_app.command("export")
def labels_export(
    bag: list[Path] = typer.Option(None, help="labels bags or recordings (repeat for several)"),
    checkpoint: Path = typer.Option(None, help="a checkpoint: the labels it was built from"),
    out: Path = typer.Option(..., help="the file to write: .jsonl (JSON lines) or .csv", callback=writable_file),
    every: bool = typer.Option(False, "--all", help="every label given, corrections too (default: the latest per labeller and episode)"),
) -> None:
    """Write labels to a plain file (fields: task, source, episode, length, return, labeller, stamp_ns)."""
    from ..labelling.label_files import SUFFIXES, latest, write_labels

    if out.suffix.lower() not in SUFFIXES:
        raise typer.BadParameter(f"--out must end in .jsonl or .csv, got {out.name!r}")
    records = _label_records(bag, checkpoint, None)
    records = records if every else latest(records)
    write_labels(records, out)
    typer.echo(f"wrote {len(records)} label(s) to {out}")


@labels_app.command("import")
def labels_import(
    file: Path = typer.Option(..., help="a labels file (.jsonl or .csv), as `nmrm labels export` writes"),
    out: Path = typer.Option(..., help="the labels-only bag to create", callback=writable_dir),
) -> None:
    """Turn a labels file into a labels-only bag, which `nmrm train --bag RECORDING --bag OUT` joins
    to its recording (and the trainer node reads with `bags`)."""
    from ..labelling.label_files import write_labels_bag

    if out.exists() and any(out.iterdir()):
        raise typer.BadParameter(f"--out {out} exists and is not empty")
    records = _label_records(None, None, file)
    if not records:
        raise typer.BadParameter(f"{file}: no labels")
    write_labels_bag(records, out)
    typer.echo(f"wrote {len(records)} label(s) to the labels bag {out}")


