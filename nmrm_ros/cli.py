"""The `nmrm` command line: one entry point, one subcommand per job.

Built on typer (click underneath). Heavy imports (torch, rclpy, gymnasium) happen inside the
subcommands, so `nmrm --help` stays fast.
"""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(
    name="nmrm",
    help="Non-Markovian reward modelling with MIL, served to RL agents over ROS 2.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """Non-Markovian reward modelling with MIL, served to RL agents over ROS 2."""


@app.command()
def info() -> None:
    """Print versions and where the ROS 2 packages of this install are found."""
    import os

    import nmrm_ros

    typer.echo(f"nmrm_ros {nmrm_ros.__version__}")
    try:
        from ament_index_python.packages import get_package_prefix

        for pkg in ("nmrm_ros", "nmrm_msgs", "rclpy"):
            typer.echo(f"  {pkg:10s} prefix: {get_package_prefix(pkg)}")
    except Exception as exc:  # noqa: BLE001 - report, don't crash an info command
        typer.echo(f"  ament index: {exc} (AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH')})")
    for mod in ("rclpy", "torch", "gymnasium", "stable_baselines3", "numpy", "mcap"):
        try:
            m = __import__(mod)
            typer.echo(f"  {mod:18s} {getattr(m, '__version__', '(no version)')}")
        except ImportError as exc:
            typer.echo(f"  {mod:18s} missing: {exc}")


dataset_app = typer.Typer(help="Generate labelled trajectory datasets (screened tasks, toy bags).",
                          no_args_is_help=True)
app.add_typer(dataset_app, name="dataset")


@dataset_app.command("screen")
def dataset_screen(
    task: str = typer.Option(..., help="timer | moving | key | charger | lunar_lander"),
    n: int = typer.Option(5000, help="trajectories to keep"),
    seed: int = typer.Option(0, help="seed of the simulator and the policy"),
    out: Path = typer.Option(None, help="write the dataset here (.npz)"),
    key_fourth_class: bool = typer.Option(False, help="Key: also screen treasure_no_key"),
    pool_size: int = typer.Option(None, help="lunar_lander: episodes in the pool (default 2n)"),
) -> None:
    """Generate a screened dataset (paper App. D.2) and print draws and time."""
    from tqdm import tqdm

    from .datasets import generate_screened
    from .tasks import check_task

    _bad_input(check_task, task)
    kwargs = {}
    if task == "lunar_lander":
        kwargs["pool_size"] = pool_size or 2 * n
    else:
        kwargs["key_fourth_class"] = key_fourth_class
        bar = tqdm(total=n, desc=f"screening {task}", unit="traj", leave=False)
        kwargs["progress"] = lambda kept, examined: (bar.update(kept - bar.n),
                                                     bar.set_postfix(draws=examined))
    ds = generate_screened(task, n, seed=seed, **kwargs)
    typer.echo(_dataset_summary(ds))
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


@dataset_app.command("toy")
def dataset_toy(
    name: str = typer.Option(..., help="toggle_switch | push_switch | dial"),
    n: int = typer.Option(5000, help="number of bags"),
    seed: int = typer.Option(0),
    out: Path = typer.Option(None, help="write the dataset here (.npz)"),
) -> None:
    """Generate a toy MIL dataset (paper App. C)."""
    from .datasets import make_toy_dataset

    ds = _bad_input(make_toy_dataset, name, n, seed=seed)
    typer.echo(_dataset_summary(ds))
    if out is not None:
        typer.echo(f"wrote {ds.save(out)}")


def _bad_input(fn, *args, **kwargs):
    """Call fn; turn a ValueError (unknown task, bad size...) into a clean CLI error."""
    try:
        return fn(*args, **kwargs)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


def _dataset_summary(ds) -> str:
    import numpy as np

    meta = ds.meta
    lines = [f"{ds.task}: {len(ds)} trajectories, state size {ds.state_size}, "
             f"return mean {ds.returns.mean():.3f} std {ds.returns.std():.3f} "
             f"min {ds.returns.min():.3f} max {ds.returns.max():.3f}"]
    if "draws" in meta:
        lines.append(f"  drawn {meta['draws']} trajectories in {meta.get('seconds', float('nan')):.2f} s "
                     f"(seed {meta.get('seed')})")
    if ds.classes is not None:
        lines.append(f"  classes used: {len(np.unique(ds.classes))}")
    return "\n".join(lines)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
