"""Rendered frames of an episode, for people to watch: encoding and naming. No ROS.

env_sim (`render:=true`) publishes `env.render()` of each step it renders as a standard
`sensor_msgs/CompressedImage` on `nmrm/frame`: `format` "jpeg" or "png", `data` the encoded
image, scaled down to at most `width` pixels wide; `header.stamp` is that of the step's
EnvObservation, and `header.frame_id` names the step, `nmrm_episode_<e>_step_<t>`, so a frame
in a bag or on the topic says which step it shows without the observation beside it.
"""

from __future__ import annotations

import io
import re

import numpy as np

FRAME_FORMATS = ("jpeg", "png")
_FRAME_ID = re.compile(r"^nmrm_episode_(\d+)_step_(\d+)$")


def frame_id(episode: int, step: int) -> str:
    """The header.frame_id of the frame of (episode, step)."""
    return f"nmrm_episode_{int(episode)}_step_{int(step)}"


def parse_frame_id(text: str) -> tuple[int, int] | None:
    """(episode, step) of a frame's header.frame_id, or None if it names no step."""
    m = _FRAME_ID.match(text or "")
    return (int(m.group(1)), int(m.group(2))) if m else None


def encode_frame(rgb: np.ndarray, width: int = 240, fmt: str = "jpeg", quality: int = 75) -> bytes:
    """An RGB frame (H, W, 3) uint8 as JPEG or PNG bytes, scaled down to at most `width` pixels
    wide (aspect kept). ValueError for anything that is not an RGB image."""
    from PIL import Image

    if fmt not in FRAME_FORMATS:
        raise ValueError(f"frame format must be one of {', '.join(FRAME_FORMATS)}, got {fmt!r}")
    frame = np.asarray(rgb)
    if frame.ndim != 3 or frame.shape[2] not in (3, 4) or frame.shape[0] < 1 or frame.shape[1] < 1:
        raise ValueError(f"render() returned {getattr(frame, 'shape', type(frame).__name__)}, "
                         f"not an RGB image (H, W, 3)")
    image = Image.fromarray(frame[..., :3].astype(np.uint8), "RGB")
    if image.width > width:
        image = image.resize((width, max(1, round(image.height * width / image.width))), Image.BILINEAR)
    out = io.BytesIO()
    if fmt == "jpeg":
        image.save(out, format="JPEG", quality=int(quality))
    else:
        image.save(out, format="PNG", optimize=False)
    return out.getvalue()


#: an image state is shown to people at least this many pixels wide (each pixel a square block)
MIN_SHOWN_WIDTH = 128


def image_state_frame(state: np.ndarray, image_shape: tuple) -> np.ndarray:
    """The RGB frame (H*k, W*k, 3) uint8 of a state whose leading values are an image
    (`TaskInfo.image_shape` (H, W, C)): what a model sees, each pixel a k x k block (k: the
    smallest making it MIN_SHOWN_WIDTH wide; no smoothing). One channel is grey; channels beyond
    the first three (stacked cameras) are not shown."""
    h, w, c = image_shape
    image = np.clip(np.asarray(state, np.float32).reshape(-1)[:h * w * c], 0, 255).astype(np.uint8).reshape(h, w, c)
    rgb = np.repeat(image[..., :1], 3, axis=2) if c < 3 else image[..., :3]
    k = max(1, -(-MIN_SHOWN_WIDTH // w))
    return np.repeat(np.repeat(rgb, k, axis=0), k, axis=1)
