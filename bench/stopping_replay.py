"""Replay the plateau schedule's stopping rule with less patience on finished training runs.

    .venv/bin/python bench/stopping_replay.py runs/time_to_accuracy/*/*.json --patience 50 40 30 20

A checkpoint's metrics keep every trained member's validation loss per epoch (`val_loss_history`).
Under the plateau schedule a member's learning-rate cuts depend only on its own validation losses,
not on the patience, so a run with patience P' < P is the run with patience P cut short: up to the
epoch where the member would have stopped, its losses are the same (exactly so for bags of one
length; where lengths vary, leaving a finished member out of the batch changes the last bits of
the others' rounding, see docs/results/findings.md). This script finds, per member, that epoch and
the best validation loss reached by then, against the recorded run's.

Printed per run and patience: the run's epochs (the last member's stop), member-epochs (the
members' epochs summed: what the training computes, as a finished member is left out of the
forward and backward), and each member's best validation loss as a ratio to the recorded run's
(1.000: the same weights would be kept). Only runs trained with schedule plateau and
min_improvement 0 are replayed (the others are listed as skipped). A member the run stopped early
as not fitted (keep_members fitted) keeps its last loss afterwards; the replay, which does not
know that rule, stops it later, so its member-epochs are an upper bound. Reads files; trains nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def member_stop(losses: np.ndarray, patience: int, plateau_patience: int, factor: float,
                min_lr_ratio: float) -> int:
    """The epoch (1-based) at which a member with validation losses `losses` (per epoch) is done
    under the plateau schedule with `patience`; len(losses) if it is not done by then."""
    best, best_epoch, since_cut, lr = np.inf, 0, 0, 1.0
    for epoch, v in enumerate(losses, start=1):
        since_cut += 1
        if v < best:
            best, best_epoch, since_cut = v, epoch, 0
        if since_cut >= plateau_patience:
            lr, since_cut = lr * factor, 0
        if lr < max(min_lr_ratio, 1e-12) or epoch - best_epoch >= patience:
            return epoch
    return len(losses)


def replay(record: dict, patience: list) -> list | str:
    """Per patience: (epochs, member-epochs, [best-loss ratio per member]); a string if skipped."""
    cfg, metrics = record.get("train_config", {}), record.get("metrics", {})
    history = metrics.get("val_loss_history")
    if not history:
        return "no val_loss_history (trained before it was recorded)"
    if cfg.get("schedule") != "plateau" or cfg.get("min_improvement", 0.0):
        return f"schedule {cfg.get('schedule')}, min_improvement {cfg.get('min_improvement')}: not replayable"
    losses = np.asarray(history, dtype=float).T  # (K, epochs)
    rows = []
    recorded = [member_stop(m, cfg["patience"], cfg["plateau_patience"], cfg["plateau_factor"],
                            cfg["min_lr_ratio"]) for m in losses]
    for p in patience:
        stops = [member_stop(m, p, cfg["plateau_patience"], cfg["plateau_factor"], cfg["min_lr_ratio"])
                 for m in losses]
        ratios = [float(m[:s].min() / m[:r].min()) if m[:r].min() > 0 else float(m[:s].min() == 0)
                  for m, s, r in zip(losses, stops, recorded)]
        rows.append((p, max(stops), sum(stops), ratios))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", type=Path, help="checkpoint .json files")
    parser.add_argument("--patience", nargs="+", type=int, default=[50, 40, 30, 20])
    a = parser.parse_args()
    for path in a.checkpoints:
        record = json.loads(path.read_text())
        result = replay(record, a.patience)
        if isinstance(result, str):
            print(f"{path}: skipped: {result}")
            continue
        print(f"{path} ({record.get('task')}, patience {record['train_config']['patience']} recorded)")
        for p, epochs, member_epochs, ratios in result:
            print(f"  patience {p:3d}: {epochs:4d} epochs, {member_epochs:5d} member-epochs; best validation loss / "
                  f"recorded per member: " + " ".join(f"{r:.3f}" for r in ratios))


if __name__ == "__main__":
    main()
