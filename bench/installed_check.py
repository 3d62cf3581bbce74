"""Benchmarks measure HEAD: refuse to run when the installed nmrm_ros differs from the source tree.

The bench scripts (and the node executables they start) import the *installed* package
(`bash scripts/setup_env.sh` installs it with `pip install .`, not editable); after an edit, a
bench would otherwise time the previous code. Imported for its effect by every bench script.
"""

from __future__ import annotations

import filecmp
import importlib.util
import sys
from pathlib import Path

SOURCE = Path(__file__).resolve().parents[1] / "nmrm_ros"


def stale_files() -> list[str]:
    """Package files (relative paths) that differ between the source tree and the install."""
    spec = importlib.util.find_spec("nmrm_ros")
    if spec is None or spec.origin is None:
        return ["(nmrm_ros is not installed)"]
    installed = Path(spec.origin).resolve().parent
    if installed == SOURCE:
        return []
    ours = {p.relative_to(SOURCE) for p in SOURCE.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    theirs = {p.relative_to(installed) for p in installed.rglob("*")
              if p.is_file() and "__pycache__" not in p.parts}
    differ = sorted(str(p) for p in ours ^ theirs)
    differ += sorted(str(p) for p in ours & theirs if not filecmp.cmp(SOURCE / p, installed / p, shallow=False))
    return differ


def require_current_install() -> None:
    stale = stale_files()
    if stale:
        more = f" and {len(stale) - 3} more" if len(stale) > 3 else ""
        sys.exit(f"bench: the installed nmrm_ros differs from the source tree ({', '.join(stale[:3])}{more}): "
                 f"run `bash scripts/setup_env.sh` first")


require_current_install()
