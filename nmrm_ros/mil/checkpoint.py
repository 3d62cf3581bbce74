"""Checkpoints: a plain state dict (`<name>.pt`, loaded with weights_only=True) beside JSON
metadata (`<name>.json`: architecture and sizes, task, normalisation, training config, seed,
metrics, package version). A checkpoint holds a `MILEnsemble` (a single model is an ensemble of
one): the K members' stacked weights, and in its metadata "ensemble": members, seeds, serving
member. `load_checkpoint` always returns a `MILEnsemble`; a checkpoint of one `MILRewardModel`
written before that (no "ensemble" entry) loads as an ensemble of one. The .json carries the SHA-256 of its .pt, so a
.pt and a .json from different trainings are refused; the normalisation lives in the weights (the
model's buffers) and the .json copy must agree with it. A checkpoint that does not match what the
caller asks for, or whose weights do not match its own metadata, is refused with a clear error."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import torch

from .. import __version__
from .ensemble import MILEnsemble, as_ensemble
from .models import ModelConfig, MILRewardModel, build_model

FORMAT = "nmrm_ros.mil_checkpoint/1"


class CheckpointError(ValueError):
    """A checkpoint is missing, malformed, or does not match what was asked for."""


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


def save_checkpoint(model: MILRewardModel | MILEnsemble, path: str | Path, task: str, **meta) -> Path:
    """Write `<path>.pt` and `<path>.json` of `model` as an ensemble (a single model: of one);
    returns the .pt path. meta["ensemble"] defaults to the members and the serving member."""
    model = as_ensemble(model)
    meta["ensemble"] = {"members": model.members, "serving_member": int(model.serving_member),
                        **(meta.get("ensemble") or {})}
    weights, info = checkpoint_paths(path)
    weights.parent.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), weights)
    record = {
        "format": FORMAT,
        "package_version": __version__,
        "weights_sha256": _sha256(weights),
        "task": task,
        "model": model.config.to_dict(),
        "normalisation": _normalisation(model),
        **meta,
    }
    tmp = info.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=2))
    os.replace(tmp, info)  # the metadata appears whole, after its weights
    return weights


#: metadata entries save_checkpoint writes itself (from the model), not from its caller
WRITTEN_BY_SAVE = ("format", "package_version", "weights_sha256", "task", "model", "normalisation")


def caller_meta(meta: dict) -> dict:
    """A loaded checkpoint's metadata without what save_checkpoint derives from the model: what to
    pass again when saving a modified copy (`save_checkpoint(copy, path, task=meta["task"], **caller_meta(meta))`)."""
    return {k: v for k, v in meta.items() if k not in WRITTEN_BY_SAVE}


def _normalisation(model) -> dict:
    """The normalisation held in the weights (model buffers), as the .json records it."""
    return {"shift": model.input_shift.tolist(), "scale": model.input_scale.tolist(),
            "return_scale": float(model.return_scale)}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_checkpoint(path: str | Path, architecture: str | None = None,
                    input_size: int | None = None,
                    task: str | None = None) -> tuple[MILEnsemble, dict]:
    """Rebuild the ensemble (a single model's checkpoint: an ensemble of one) from the metadata
    and load the weights (eval mode).

    Raises CheckpointError if a file is missing or malformed, or if the checkpoint's architecture,
    input size or task differs from the one asked for.
    """
    weights, info = checkpoint_paths(path)
    for p in (weights, info):
        if not p.is_file():
            raise CheckpointError(f"checkpoint file missing: {p}")
    try:
        record = json.loads(info.read_text())
        config = ModelConfig.from_dict(record["model"])
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise CheckpointError(f"malformed checkpoint metadata {info}: {exc}") from None
    if record.get("format") != FORMAT:
        raise CheckpointError(f"{info}: unknown checkpoint format {record.get('format')!r}")
    if architecture is not None and config.architecture != architecture:
        raise CheckpointError(f"checkpoint {weights} is a {config.architecture} model, "
                              f"not the requested {architecture}")
    if input_size is not None and config.input_size != input_size:
        raise CheckpointError(f"checkpoint {weights} takes states of size {config.input_size}, "
                              f"not {input_size}")
    if task is not None and record.get("task") != task:
        raise CheckpointError(f"checkpoint {weights} was trained on task {record.get('task')!r}, "
                              f"not {task!r}")
    expected = record.get("weights_sha256")
    actual = _sha256(weights) if expected is not None else None
    if actual != expected:
        raise CheckpointError(f"checkpoint weights {weights} do not belong to {info} (SHA-256 "
                              f"{actual[:12]}..., the metadata expects {expected[:12]}...): "
                              f"a .pt and a .json from different trainings?")
    if weights.stat().st_size == 0:
        raise CheckpointError(f"cannot read checkpoint weights {weights}: the file is empty")
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling/format failure is a bad checkpoint
        raise CheckpointError(f"cannot read checkpoint weights {weights}: "
                              f"{type(exc).__name__}: {str(exc).strip() or 'unreadable'}") from None
    ensemble = record.get("ensemble")
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
        ours = _normalisation(model)
        try:
            same = all(torch.allclose(torch.tensor(norm[k], dtype=torch.float64),
                                      torch.tensor(ours[k], dtype=torch.float64), rtol=1e-5, atol=1e-7)
                       for k in ours)
        except (KeyError, TypeError, RuntimeError, ValueError):
            same = False
        if not same:
            raise CheckpointError(f"{info}: its normalisation differs from the one in the weights "
                                  f"{weights} (the weights hold the one used; was the .json edited?)")
    return as_ensemble(model).eval(), record
