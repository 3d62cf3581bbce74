"""Checkpoints: a plain state dict (`<name>.pt`, loaded with weights_only=True) beside JSON
metadata (`<name>.json`), typed here as `CheckpointMeta`: the task, the model's architecture and
sizes, its normalisation, the ensemble (members, seeds, serving member), where its data came from
(a `DataSource` that says how to make it again), the training config, metrics, calibration and
provenance (package version, seeds, the SHA-256 of its weights), with a format version.

A checkpoint holds a `MILEnsemble` (a single model is an ensemble of one). `Run.save`
(`mil/run.py`) is the only writer; `load_checkpoint` is the only reader and loads every
checkpoint written since the ensemble-of-one change (format 1: the data source a string; format
2: an object) and the single-model checkpoints before it (as an ensemble of one). The .json
carries the SHA-256 of its .pt, so a .pt and a .json from different trainings are refused; the
normalisation lives in the weights (the model's buffers) and the .json copy must agree with it. A
checkpoint that does not match what the caller asks for, or whose weights do not match its own
metadata, is refused with a clear one-line `CheckpointError`."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import torch

from .ensemble import MILEnsemble, as_ensemble
from .models import ModelConfig, build_model
from .served_state import DEFAULT_SERVED_STATE, check_served_state

#: the format written now (2: the data source is an object) and every one still read
FORMAT = "nmrm_ros.mil_checkpoint/2"
FORMATS = ("nmrm_ros.mil_checkpoint/1", FORMAT)


class CheckpointError(ValueError):
    """A checkpoint is missing, malformed, or does not match what was asked for."""


@dataclass(frozen=True)
class DataSource:
    """Where a model's training data came from, so that it can be made again.

    kind: "toy" or "screened" (generated: `task`, `n` episodes, data `seed`), "bags" (recordings
    at `paths`), "file" (a dataset .npz at paths[0]), "live" (labels collected by the trainer
    node), "" (not recorded)."""

    kind: str = ""
    task: str = ""
    n: int = 0
    seed: int = 0
    paths: tuple = ()

    KINDS = ("toy", "screened", "bags", "file", "live", "")

    def __post_init__(self) -> None:
        if self.kind not in self.KINDS:
            raise ValueError(f"unknown data source kind {self.kind!r}; one of {', '.join(map(repr, self.KINDS))}")

    @classmethod
    def generated(cls, task: str, n: int, seed: int) -> "DataSource":
        """`n` episodes of `task` generated with data seed `seed` (a toy task's, else screened)."""
        from ..datasets import TOY_DATASETS

        return cls("toy" if task in TOY_DATASETS else "screened", task, int(n), int(seed))

    @classmethod
    def bags(cls, paths) -> "DataSource":
        return cls("bags", paths=tuple(str(p) for p in paths))

    @classmethod
    def file(cls, path) -> "DataSource":
        return cls("file", paths=(str(path),))

    @property
    def regenerable(self) -> bool:
        """Whether the data can be made again from this record alone (generated, or files)."""
        return (self.kind in ("toy", "screened") and self.n > 0) or (self.kind in ("bags", "file") and bool(self.paths))

    def __str__(self) -> str:
        """The one-line form (as format 1 wrote it): toy:key:n=100:seed=0, bags:a.mcap,b.mcap, a path."""
        if self.kind in ("toy", "screened"):
            return f"{self.kind}:{self.task}:n={self.n}:seed={self.seed}"
        if self.kind == "bags":
            return "bags:" + ",".join(self.paths)
        if self.kind == "file":
            return self.paths[0] if self.paths else ""
        return "live labels" if self.kind == "live" else ""

    @classmethod
    def parse(cls, text: str) -> "DataSource":
        """The inverse of str() (format 1's strings; a task may hold ':', e.g. gym:CartPole-v1);
        any other non-empty string is a dataset file's path (format 1 wrote `--data` so)."""
        text = text or ""
        generated = re.fullmatch(r"(toy|screened):(.+):n=(\d+):seed=(\d+)", text)
        if generated:
            kind, task, n, seed = generated.groups()
            return cls(kind, task, int(n), int(seed))
        if text.startswith("bags:"):
            return cls.bags(p for p in text[5:].split(",") if p)
        if text == "live labels":
            return cls("live")
        return cls.file(text) if text else cls()

    def to_dict(self) -> dict:
        return {"kind": self.kind, "task": self.task, "n": self.n, "seed": self.seed, "paths": list(self.paths)}

    @classmethod
    def from_record(cls, value) -> "DataSource":
        """Format 2's object, or format 1's string."""
        if isinstance(value, dict):
            return cls(str(value.get("kind", "")), str(value.get("task", "")), int(value.get("n", 0)),
                       int(value.get("seed", 0)), tuple(str(p) for p in value.get("paths", ())))
        return cls.parse(value if isinstance(value, str) else "")


@dataclass(frozen=True)
class DataInfo:
    """The training data: its source, how many episodes, and the dataset's own metadata (labels,
    comparisons, the generator's settings); extra: entries this version does not know."""

    source: DataSource = DataSource()
    n: int | None = None
    meta: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EnsembleInfo:
    """The members: how many, which serves its hidden state, their weight and split seeds, how
    they were split; when members were left out (keep_members "best" or "fitted"), the
    candidates trained, their seeds and validation losses, and `kept`: the candidates' indices
    that are the members (best: also `chosen`, the one kept)."""

    members: int = 1
    serving_member: int = 0
    seeds: list | None = None
    split_seeds: list | None = None
    split_mode: str | None = None
    candidates: int | None = None
    candidate_seeds: list | None = None
    chosen: int | None = None
    candidate_val_loss: list | None = None
    kept: list | None = None
    extra: dict = field(default_factory=dict)  # entries this version does not know


@dataclass(frozen=True)
class CheckpointMeta:
    """A checkpoint's metadata (its .json), typed. `extra` keeps entries this version does not
    know (written back unchanged when a copy is saved)."""

    task: str | None
    model: ModelConfig
    ensemble: EnsembleInfo = EnsembleInfo()
    data: DataInfo = DataInfo()
    train_config: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    calibration: dict | None = None
    normalisation: dict = field(default_factory=dict)
    seed: int | None = None
    split_seed: int | None = None
    package_version: str = ""
    weights_sha256: str | None = None
    #: the SHA-256 of the frozen image encoder's weights file its task spec names, when it was saved
    encoder_sha256: str | None = None
    format: str = FORMAT
    extra: dict = field(default_factory=dict)

    @property
    def served_state(self) -> str:
        """What the model serves unless told otherwise: its training config's `served_state`
        (config/mil_training.yaml, per task, chosen by the agents it gave), else the default."""
        return check_served_state(self.train_config.get("served_state") or DEFAULT_SERVED_STATE)

    @property
    def return_units(self) -> bool:
        """Whether the model pays in its labels' units: False for a model trained from comparisons
        alone and not calibrated since (comparisons fix the returns only up to a scale and an
        offset; `nmrm calibrate`)."""
        return self.calibration is not None or self.train_config.get("feedback", "returns") != "preferences"

    def replace(self, **changes) -> "CheckpointMeta":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The .json's record (format 2)."""
        ens = {k: v for k, v in dataclasses.asdict(self.ensemble).items() if v is not None and k != "extra"}
        record = {"format": FORMAT, "package_version": self.package_version,
                  "weights_sha256": self.weights_sha256, "task": self.task, "model": self.model.to_dict(),
                  "normalisation": self.normalisation, "ensemble": {**ens, **self.ensemble.extra},
                  "data": {"source": self.data.source.to_dict(), "n": self.data.n, "meta": self.data.meta,
                           **self.data.extra},
                  "train_config": self.train_config, "metrics": self.metrics}
        for key in ("seed", "split_seed", "calibration", "encoder_sha256"):
            if getattr(self, key) is not None:
                record[key] = getattr(self, key)
        return {**record, **self.extra}

    @classmethod
    def from_dict(cls, record: dict) -> "CheckpointMeta":
        """Any format in FORMATS, and the single-model records before "ensemble" (one member).
        KeyError/TypeError/ValueError if malformed."""
        known = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        ens = _mapping(record.get("ensemble"))
        ens_fields = {f.name for f in dataclasses.fields(EnsembleInfo)} - {"extra"}
        data = _mapping(record.get("data"))
        return cls(
            task=record.get("task"), model=ModelConfig.from_dict(record["model"]),
            ensemble=EnsembleInfo(**{k: v for k, v in ens.items() if k in ens_fields},
                                  extra={k: v for k, v in ens.items() if k not in ens_fields}),
            data=DataInfo(DataSource.from_record(data.get("source")), data.get("n"), _mapping(data.get("meta")),
                          {k: v for k, v in data.items() if k not in ("source", "n", "meta")}),
            train_config=_mapping(record.get("train_config")), metrics=_mapping(record.get("metrics")),
            calibration=record.get("calibration"), normalisation=dict(record.get("normalisation") or {}),
            seed=record.get("seed"), split_seed=record.get("split_seed"),
            package_version=str(record.get("package_version", "")), weights_sha256=record.get("weights_sha256"),
            encoder_sha256=record.get("encoder_sha256"), format=str(record.get("format")),
            extra={k: v for k, v in record.items() if k not in known})


def _mapping(value) -> dict:
    """A record's entry that should be an object: a copy of it, {} if it is anything else."""
    return dict(value) if isinstance(value, dict) else {}


def checkpoint_paths(path: str | Path) -> tuple[Path, Path]:
    """(weights .pt, metadata .json) for a path given with or without either suffix."""
    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".pt", ".json") else path
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def recorded_weights_sha256(path: str | Path) -> str | None:
    """The SHA-256 of the weights that a checkpoint's metadata records (None without metadata):
    which model a run used, even after a checkpoint of the same name is trained again."""
    info = checkpoint_paths(path)[1]
    try:
        return json.loads(info.read_text()).get("weights_sha256")
    except (OSError, ValueError):
        return None


def normalisation_of(model) -> dict:
    """The normalisation held in the weights (model buffers), as the .json records it."""
    return {"shift": model.input_shift.tolist(), "scale": model.input_scale.tolist(),
            "return_scale": float(model.return_scale)}


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_encoder_weights(meta: CheckpointMeta, weights: Path) -> None:
    """CheckpointError where the frozen encoder's weights file that the checkpoint's task spec
    names now holds other weights than when the model was saved (its states would be another
    encoder's features); nothing where no encoder SHA-256 is recorded or the file is not here."""
    from ..tasks.gym_task import encoder_weights_changed

    changed = encoder_weights_changed(meta.task, meta.encoder_sha256)
    if changed:
        raise CheckpointError(f"checkpoint {weights} was trained on states of another encoder ({changed}): "
                              f"restore that file, or train the model again on states of the new encoder")


def load_checkpoint(path: str | Path, architecture: str | None = None,
                    input_size: int | None = None,
                    task: str | None = None) -> tuple[MILEnsemble, CheckpointMeta]:
    """Rebuild the ensemble (a single model's checkpoint: an ensemble of one) from the metadata
    and load the weights (eval mode); (ensemble, its metadata).

    Raises CheckpointError if a file is missing or malformed, or if the checkpoint's architecture,
    input size or task differs from the one asked for.
    """
    weights, info = checkpoint_paths(path)
    for p in (weights, info):
        if not p.is_file():
            raise CheckpointError(f"checkpoint file missing: {p}")
    try:
        record = json.loads(info.read_text())
        if record.get("format") not in FORMATS:
            raise CheckpointError(f"{info}: unknown checkpoint format {record.get('format')!r}")
        meta = CheckpointMeta.from_dict(record)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        if isinstance(exc, CheckpointError):
            raise
        raise CheckpointError(f"malformed checkpoint metadata {info}: {exc}") from None
    config = meta.model
    if architecture is not None and config.architecture != architecture:
        raise CheckpointError(f"checkpoint {weights} is a {config.architecture} model, "
                              f"not the requested {architecture}")
    if input_size is not None and config.input_size != input_size:
        raise CheckpointError(f"checkpoint {weights} takes states of size {config.input_size}, "
                              f"not {input_size}")
    if task is not None and meta.task != task:
        raise CheckpointError(f"checkpoint {weights} was trained on task {record.get('task')!r}, "
                              f"not {task!r}")
    expected = meta.weights_sha256
    actual = sha256_of(weights) if expected is not None else None
    if actual != expected:
        raise CheckpointError(f"checkpoint weights {weights} do not belong to {info} (SHA-256 "
                              f"{actual[:12]}..., the metadata expects {expected[:12]}...): "
                              f"a .pt and a .json from different trainings?")
    if weights.stat().st_size == 0:
        raise CheckpointError(f"cannot read checkpoint weights {weights}: the file is empty")
    check_encoder_weights(meta, weights)
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling/format failure is a bad checkpoint
        raise CheckpointError(f"cannot read checkpoint weights {weights}: "
                              f"{type(exc).__name__}: {str(exc).strip() or 'unreadable'}") from None
    ensemble = record.get("ensemble")  # None: a single model, before ensembles
    try:
        if ensemble is not None:
            model = MILEnsemble(config, int(ensemble["members"]))
        else:
            model = build_model(config)
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"malformed checkpoint metadata {info}: {exc}") from None
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        what = f"{ensemble['members']}-member ensemble, " if ensemble is not None else ""
        raise CheckpointError(f"checkpoint weights {weights} do not match their metadata "
                              f"({what}{config.architecture}, input {config.input_size}): "
                              f"{str(exc).splitlines()[0]}") from None
    norm = record.get("normalisation")
    if norm is not None:
        ours = normalisation_of(model)
        try:
            same = all(torch.allclose(torch.tensor(norm[k], dtype=torch.float64),
                                      torch.tensor(ours[k], dtype=torch.float64), rtol=1e-5, atol=1e-7)
                       for k in ours)
        except (KeyError, TypeError, RuntimeError, ValueError):
            same = False
        if not same:
            raise CheckpointError(f"{info}: its normalisation differs from the one in the weights "
                                  f"{weights} (the weights hold the one used; was the .json edited?)")
    return as_ensemble(model).eval(), meta
