"""The `nmrm` typer app, its root callback and `nmrm info`; the command groups register on it."""

from __future__ import annotations

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
    from ..ros.ament_paths import ensure_ament_prefix_path
    from ..ros.discovery import use_discovery_profile

    ensure_ament_prefix_path()  # no `source` needed: our packages know where they are installed
    use_discovery_profile()  # for the nodes `nmrm launch` starts and in-process rclpy


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


