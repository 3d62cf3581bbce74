"""A reward model's life in one object: `Run` = a trained `MILEnsemble` + its typed metadata.

`pipeline.fit(...)` and `retrain.retrain(...)` make one, `Run.load(path)` reads one back,
`Run.save(path)` is the only code that writes a checkpoint, and `run.replace(model=..., ...)` is a
modified copy (a calibrated model keeps everything else it knew)::

    run = fit(ds, "csc_lstm", load_train_config("key"), out="runs/key")   # trains and saves
    run = Run.load("runs/key", task="key")                                # run.model, run.meta
    run.replace(model=calibrated, calibration={...}).save("runs/key_cal")

Serving goes through `OnlineRewardModel.from_checkpoint(path)`.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from .. import __version__
from .checkpoint import (FORMAT, CheckpointMeta, DataInfo, DataSource, EnsembleInfo, checkpoint_paths,
                         load_checkpoint, normalisation_of, sha256_of)
from .ensemble import MILEnsemble, as_ensemble


@dataclass
class Run:
    """A reward model and what is known about it (what a checkpoint holds).

    model: the ensemble (a single model: of one); meta: its `CheckpointMeta`; train: how its
    training went (per-member best epochs, losses, history; not saved, None for a loaded run);
    checkpoint: the .pt it was saved to or loaded from (None: not saved)."""

    model: MILEnsemble
    meta: CheckpointMeta
    train: object | None = None
    checkpoint: Path | None = None

    @classmethod
    def of(cls, model, task: str, *, ensemble: EnsembleInfo | None = None, data: DataInfo | DataSource | None = None,
           train=None, **fields) -> "Run":
        """A new run of `model` (a MILRewardModel becomes an ensemble of one) on `task`; the
        architecture, sizes, normalisation and member count come from the model. ensemble:
        seeds etc. (default: its members, serving member); data: a DataInfo, or just its
        source; fields: the other CheckpointMeta fields (train_config, metrics, seed, ...)."""
        model = as_ensemble(model)
        if ensemble is None:
            ensemble = EnsembleInfo(model.members, int(model.serving_member))
        if ensemble.members != model.members or ensemble.serving_member != int(model.serving_member):
            raise ValueError(f"ensemble record ({ensemble.members} members, serving {ensemble.serving_member}) "
                             f"differs from the model ({model.members}, serving {int(model.serving_member)})")
        if isinstance(data, DataSource):
            data = DataInfo(data)
        meta = CheckpointMeta(task=task, model=model.config, ensemble=ensemble, data=data or DataInfo(), **fields)
        return cls(model, meta, train=train)

    @classmethod
    def load(cls, path: str | Path, *, task: str | None = None, architecture: str | None = None,
             input_size: int | None = None) -> "Run":
        """The run saved at `path` (.pt, .json or the stem); CheckpointError (one line) if it is
        missing, malformed, or not of the task / architecture / input size asked for."""
        model, meta = load_checkpoint(path, architecture=architecture, input_size=input_size, task=task)
        return cls(model, meta, checkpoint=checkpoint_paths(path)[0])

    def replace(self, model=None, **meta_changes) -> "Run":
        """A copy with another model (same architecture and members) and/or metadata fields changed;
        not saved (checkpoint None), training record dropped."""
        model = self.model if model is None else as_ensemble(model)
        if model.config != self.meta.model or model.members != self.meta.ensemble.members:
            raise ValueError("Run.replace: the new model's architecture, sizes or members differ; use Run.of")
        return Run(model, self.meta.replace(**meta_changes))

    def save(self, path: str | Path) -> Path:
        """Write `<path>.pt` (the weights) and then `<path>.json` (the metadata, with the weights'
        SHA-256, the package version and the normalisation read from the weights); returns the .pt.
        The metadata appears whole and after its weights, so a reader never sees a half-written pair."""
        weights, info = checkpoint_paths(path)
        weights.parent.mkdir(parents=True, exist_ok=True)
        torch.save(self.model.state_dict(), weights)
        from ..tasks.gym_task import encoder_weights_sha256

        # a frozen encoder's weights: the dataset's record first (its states are those features)
        encoder = (self.meta.data.meta or {}).get("encoder_sha256")
        if not encoder:  # data of older versions: the file's, as it is now
            now = encoder_weights_sha256(self.meta.task)
            encoder = now[1] if now else self.meta.encoder_sha256
        self.meta = self.meta.replace(model=self.model.config, normalisation=normalisation_of(self.model),
                                      encoder_sha256=encoder,
                                      package_version=__version__, weights_sha256=sha256_of(weights), format=FORMAT,
                                      ensemble=dataclasses.replace(self.meta.ensemble, members=self.model.members,
                                                                   serving_member=int(self.model.serving_member)))
        tmp = info.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self.meta.to_dict(), indent=2))
        os.replace(tmp, info)
        self.checkpoint = weights
        return weights

    # what a training run reports, read from its metadata
    @property
    def test_metrics(self) -> dict | None:
        """The ensemble's (mean) prediction on the test split; None when the members have test
        splits of their own (split_mode per_member, K > 1) or there is no test split."""
        return self.meta.metrics.get("test")

    @property
    def val_metrics(self) -> dict | None:
        return self.meta.metrics.get("val")

    @property
    def member_test(self) -> list:
        """K dicts of test metrics, each member on its own test split."""
        return self.meta.metrics.get("member_test", [])

    @property
    def member_val(self) -> list:
        return self.meta.metrics.get("member_val", [])

    @property
    def seeds(self) -> list:
        """Each member's weight (and shuffle) seed."""
        return self.meta.ensemble.seeds or []

    @property
    def split_seeds(self) -> list:
        return self.meta.ensemble.split_seeds or []

    @property
    def chosen(self) -> int | None:
        """keep_members best: the kept candidate's index among those trained (None: all kept)."""
        return self.meta.ensemble.chosen

    @property
    def kept(self) -> list | None:
        """The candidates' indices that are the members, when some were left out (keep_members
        best or fitted); None: every member trained was kept."""
        e = self.meta.ensemble
        return e.kept if e.kept is not None else None if e.chosen is None else [e.chosen]
