"""A user's own image encoder, frozen, in front of a task's state (task spec `encoder=`).

    gym:CarRacing-v3,image=64x64,encoder=my_vision:make_encoder,encoder_weights=/abs/enc.pt

`encoder=<module>:<attribute>` names a `torch.nn.Module`, a module class, or a factory returning
one (called without arguments, torch's generator seeded 0 meanwhile, so that a module without
weights is the same random one in every process); `encoder_weights=<path>` (optional) is a state
dict the module loads (`torch.load(..., weights_only=True)`). The module is put in eval mode and never trained.
It reads the observation's image (resized and stacked as without an encoder:
`gym_task.ObservationLayout`) as a float32 tensor (1, C, H, W) with values in 0..1 — the
torchvision convention — and its output, flattened, is the image's part of the state: the state is
[features (F), the rest of the observation], a vector.

So the features are computed once per frame, when the environment steps (a dataset stores them),
and a reward model, an ensemble, a checkpoint, `nmrm check`, `nmrm explain` and the agents treat
the task as a vector task: training costs what a state model costs. The encoder's weights are not
in a checkpoint: the task spec (recorded in it) names them, so keep that file as it was trained
with: a checkpoint records the file's SHA-256 (`encoder_sha256`) when the model is saved, and loading
it where that file now holds other weights is refused (`gym_task.encoder_weights_sha256`,
`mil.checkpoint.load_checkpoint`). A dataset
does not record it yet, so a model trained after the file changed, from a dataset encoded before,
is not caught.
"""

from __future__ import annotations

import hashlib
import importlib
from pathlib import Path

import numpy as np


class EncoderError(ValueError):
    """An encoder that does not load or run (one line, says why; `gym_task` raises it as a
    TaskSpecError)."""


class FrozenEncoder:
    """`encoder(image)`: an image (H, W, C) uint8 -> its features (F,) float32, by the user's
    module `target` (with `weights`, if given), frozen. `size` is F; `sha256` the weights file's
    (or ""). Every failure to load or to run it is an `EncoderError` (one line)."""

    def __init__(self, target: str, weights: str | None, image_shape: tuple, task: str) -> None:
        import torch

        self._error = lambda why: EncoderError(f"task {task!r}: encoder={target}: {why}")
        module_name, _, attribute = str(target).partition(":")
        if not module_name or not attribute:
            raise EncoderError(f"task {task!r}: encoder must be <module>:<attribute>, got {target!r}")
        try:
            imported = importlib.import_module(module_name)
        except Exception as exc:  # noqa: BLE001 - the user's module (a syntax error, a raise): one line
            raise self._error(f"cannot import {module_name!r} ({type(exc).__name__}: {_line(exc)})") from None
        try:
            obj = getattr(imported, attribute)
        except AttributeError:
            raise self._error(f"{module_name!r} has no {attribute!r}") from None
        try:
            with torch.random.fork_rng(devices=[]):  # its initial weights: seed 0, the caller's stream untouched
                torch.manual_seed(0)
                module = obj if isinstance(obj, torch.nn.Module) else obj()
        except Exception as exc:  # noqa: BLE001 - the user's code: one line
            raise self._error(f"building it failed: {type(exc).__name__}: {_line(exc)}") from None
        if not isinstance(module, torch.nn.Module):
            raise self._error(f"it gave a {type(module).__name__}, not a torch.nn.Module")
        self.sha256 = ""
        if weights:
            path = Path(str(weights)).expanduser()
            try:
                self.sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
                state = torch.load(path, map_location="cpu", weights_only=True)
                module.load_state_dict(state)
            except OSError as exc:
                raise self._error(f"cannot read encoder_weights {path}: {exc.strerror or exc}") from None
            except Exception as exc:  # noqa: BLE001 - a wrong or broken file: one line
                raise self._error(f"encoder_weights {path} do not fit it: {_line(exc)}") from None
        self.module = module.eval().requires_grad_(False)
        self.image_shape = tuple(int(v) for v in image_shape)
        # its size, from a noise image (an encoder that normalises each image has no features of a
        # uniform one)
        probe = np.random.default_rng(0).integers(0, 256, self.image_shape, dtype=np.uint8)
        self.size = int(self(probe).size)
        if self.size < 1:
            raise self._error("it gave no features")

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """The features (F,) float32 of one image (H, W, C) uint8."""
        import torch

        x = torch.from_numpy(np.ascontiguousarray(image, dtype=np.uint8)).permute(2, 0, 1)[None].float() / 255.0
        try:
            with torch.inference_mode():
                y = self.module(x)
            features = np.asarray(y.detach().reshape(-1).numpy(), dtype=np.float32)
        except Exception as exc:  # noqa: BLE001 - the user's module: one line
            raise self._error(f"it failed on a (1, {x.shape[1]}, {x.shape[2]}, {x.shape[3]}) image: "
                              f"{type(exc).__name__}: {_line(exc)}") from None
        if not np.all(np.isfinite(features)):
            raise self._error("its features hold NaN or inf")
        return features


def _line(exc: BaseException, limit: int = 300) -> str:
    """An exception's message on one line (a state dict's missing and unexpected keys included),
    at most `limit` characters."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."
