"""The `nmrm` command line: one entry point, one subcommand per job, one module per command group.

Built on typer (click underneath). Heavy imports (torch, rclpy, gymnasium) happen inside the
subcommands, so `nmrm --help` stays fast. The modules register their commands on `app.app` in the
order `nmrm --help` lists them.
"""

from __future__ import annotations

import signal
import sys

import typer

from .app import app

# each module registers its commands on `app`, in the order `nmrm --help` lists them
from . import dataset  # noqa: E402,F401,I001
from . import graph  # noqa: E402,F401
from . import labels  # noqa: E402,F401
from . import bag  # noqa: E402,F401
from . import lerobot  # noqa: E402,F401
from . import model  # noqa: E402,F401
from . import discovery  # noqa: E402,F401
from . import agents  # noqa: E402,F401
from . import loop  # noqa: E402,F401
from . import tls  # noqa: E402,F401

__all__ = ["app", "main"]


def _command_path(argv: list) -> str:
    """"nmrm dataset generate" for argv ["dataset", "generate", "--n", ...]: the command named."""
    command, path = typer.main.get_command(app), ["nmrm"]
    for arg in argv:
        sub = getattr(command, "commands", {}).get(arg)
        if sub is None:
            break
        command, path = sub, path + [arg]
    return " ".join(path)


def _interrupt_on_stop_signals() -> dict:
    """SIGINT and SIGTERM raise KeyboardInterrupt, so an interrupted command cleans up (e.g. no
    half-written bag is left) and exits with 128 + the signal. SIGINT is handled even where it was
    inherited as ignored (a command started with `&` from a script): `kill -INT` must stop it."""
    stopped_by: dict = {}

    def interrupt(signum, frame):
        stopped_by["signal"] = int(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)
    return stopped_by


def main() -> None:
    """Console-script entry point. Errors (bad options, bad input files) are one line on stderr,
    `nmrm <command>: error: ...`, exit code 2; `--help` and no arguments print the help.

    Bad input is translated here, once: the library raises a `ValueError` (`CheckpointError`,
    `BagError`, `TaskSpecError`, `OracleError`, `LaunchError`, `CalibrationError`... all are) with a
    one-line message, and the commands let it through."""
    from typer._click import exceptions as click_errors  # typer vendors click

    stopped_by = _interrupt_on_stop_signals()
    try:
        code = app(standalone_mode=False, prog_name="nmrm")
    except click_errors.NoArgsIsHelpError:  # the help was printed already
        raise SystemExit(0) from None
    except click_errors.ClickException as exc:
        where = f"{exc.ctx.command_path}: " if getattr(exc, "ctx", None) is not None else "nmrm: "
        typer.echo(f"{where}error: {' '.join(exc.format_message().split())}", err=True)
        raise SystemExit(exc.exit_code) from None
    except ValueError as exc:  # bad input, from any command: the one translation
        typer.echo(f"{_command_path(sys.argv[1:])}: error: Invalid value: {' '.join(str(exc).split())}", err=True)
        raise SystemExit(2) from None
    except (typer.Abort, KeyboardInterrupt):
        stopped_by.setdefault("signal", int(signal.SIGINT))
    if "signal" in stopped_by:  # typer turns KeyboardInterrupt into exit code 130
        typer.echo(f"nmrm: interrupted ({signal.Signals(stopped_by['signal']).name})", err=True)
        raise SystemExit(128 + stopped_by["signal"])
    raise SystemExit(code if isinstance(code, int) else 0)




if __name__ == "__main__":
    main()
