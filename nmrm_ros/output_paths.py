"""Is an output path writable, checked before any work starts (and without leaving anything
behind)? Used by every command that writes, so a wrong `--out` is a one-line error at once, not
a traceback after an hour of training."""

from __future__ import annotations

import tempfile
from pathlib import Path


def check_writable_dir(directory: str | Path) -> None:
    """ValueError (one line) unless files can be written in `directory`, which need not exist:
    missing directories are created to try, then removed again."""
    directory = Path(directory)
    missing, probe = [], directory
    while not probe.exists() and probe != probe.parent:
        missing.append(probe)
        probe = probe.parent
    if not probe.is_dir():
        raise ValueError(f"cannot write to {directory}: {probe} is not a directory")
    created = []
    try:
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise ValueError(f"cannot write to {directory}: {exc.strerror or exc}") from None
    finally:
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                pass


def check_writable_file(path: str | Path) -> None:
    """ValueError (one line) unless a file `path` can be written (its directory may not exist yet;
    an existing directory of that name is refused)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"cannot write the file {path}: it is a directory")
    check_writable_dir(path.parent)
