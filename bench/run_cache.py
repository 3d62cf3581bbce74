"""When a benchmark's finished run still stands for today's code and defaults.

Benchmarks resume: a run whose result file exists is skipped. That is only right while the run
was made with today's training settings, and while an agent's reward model is the one it learnt
on; these two checks say when it is not (the run is then made again).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path


def stale_settings(recorded: dict | None, cfg) -> list[str]:
    """The training settings in which a finished run's recorded config differs from `cfg` (a
    TrainConfig of today's defaults), as "name old -> new"; settings added since the run are not
    compared. A run that recorded no config is stale as a whole."""
    if not recorded:
        return ["no recorded training config"]
    today = asdict(cfg)
    return [f"{k} {v!r} -> {today[k]!r}" for k, v in recorded.items() if k in today and today[k] != v]


def weights_sha256(checkpoint: Path) -> str | None:
    """The weights' SHA-256 that a checkpoint's metadata (.json beside the .pt) records."""
    meta = Path(checkpoint).with_suffix(".json")
    return json.loads(meta.read_text()).get("weights_sha256") if meta.is_file() else None
