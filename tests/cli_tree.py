"""The nmrm command tree, walked once for the tests that check every command and option."""

from __future__ import annotations

from typing import Iterator

import typer


def leaf_commands(app) -> Iterator[tuple[tuple[str, ...], object]]:
    """(command path, click command) of every leaf command of the typer `app`, e.g.
    (("labels", "export"), <command>), depth first in declaration order."""
    def walk(command, path):
        if hasattr(command, "commands"):
            for name, sub in command.commands.items():
                yield from walk(sub, (*path, name))
        else:
            yield path, command

    yield from walk(typer.main.get_command(app), ())
