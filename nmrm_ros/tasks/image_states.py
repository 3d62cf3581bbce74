"""The image of an image task's state as a standard compressed image, and back. No ROS.

On an image task (`TaskInfo.image_shape` (H, W, C)) a state is [H*W*C pixels, vector]. On the
graph and in bags its pixels do not travel as floats: they are one lossless PNG
(`sensor_msgs/CompressedImage`, format "png") on `nmrm/observation_image`, and the
EnvObservation of the same step carries the vector part only (`nmrm_ros.ros.observation_images` joins
them again for a consumer). The PNG is what Foxglove, rosbags and `mcap` show as an image:

- C = 1, 3, 4: a grey, RGB or RGBA image of H x W;
- C a multiple of 3 (RGB cameras stacked along C, `image=HxW` with several cameras): the cameras
  one above the other, an RGB image of (H * C/3) x W;
- any other C: the channels one above the other, a grey image of (H * C) x W.

PNG is lossless, so the pixels a consumer gets back are exactly those of the state (a model on
the graph sees what it sees in an agent's wrapper).
"""

from __future__ import annotations

import io
import math

import numpy as np

#: the CompressedImage.format of an observation image
IMAGE_STATE_FORMAT = "png"


def _layout(image_shape: tuple) -> tuple:
    """(PNG array shape, Pillow mode) of an image of `image_shape` (H, W, C)."""
    h, w, c = (int(v) for v in image_shape)
    if c in (3, 4):
        return (h, w, c), "RGB" if c == 3 else "RGBA"
    if c == 1:
        return (h, w), "L"
    if c % 3 == 0:
        return (h * c // 3, w, 3), "RGB"
    return (h * c, w), "L"


def encode_image_state(state, image_shape: tuple) -> bytes:
    """The PNG bytes of the leading H*W*C values of `state` (0..255; a whole state or its pixels
    only). ValueError (one line) if there are too few values or they are not whole 0..255."""
    from PIL import Image

    n = math.prod(int(v) for v in image_shape)
    values = np.asarray(state).reshape(-1)[:n]
    if values.size != n:
        raise ValueError(f"an image of {tuple(image_shape)} needs {n} values, the state has {values.size}")
    if values.dtype != np.uint8:
        if not (np.all(np.isfinite(values)) and values.min(initial=0) >= 0 and values.max(initial=0) <= 255
                and np.all(values == np.rint(values))):
            raise ValueError("the image values of the state are not whole numbers in 0..255")
        values = values.astype(np.uint8)
    h, w, c = (int(v) for v in image_shape)
    image = values.reshape(h, w, c)
    shape, mode = _layout(image_shape)
    if c % 3 == 0 and c > 3:
        image = np.concatenate([image[..., 3 * k:3 * k + 3] for k in range(c // 3)], axis=0)
    elif c not in (1, 3, 4):
        image = np.concatenate([image[..., k] for k in range(c)], axis=0)
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image.reshape(shape)), mode).save(out, format="PNG", compress_level=1)
    return out.getvalue()


def decode_image_state(data: bytes, image_shape: tuple) -> np.ndarray:
    """The H*W*C pixels (uint8, row-major H, W, C) of an observation image's PNG bytes;
    ValueError (one line) if they are not a PNG of the layout `image_shape` is sent in."""
    from PIL import Image, UnidentifiedImageError

    shape, mode = _layout(image_shape)
    try:
        with Image.open(io.BytesIO(bytes(data))) as image:
            if image.format != "PNG" or image.mode != mode:
                raise ValueError(f"observation image is a {image.format} {image.mode} image, expected a "
                                 f"PNG {mode} image")
            pixels = np.asarray(image)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"observation image cannot be decoded: {exc}") from None
    if pixels.shape != shape:
        raise ValueError(f"observation image is {pixels.shape[1]}x{pixels.shape[0]}, the task's "
                         f"{tuple(image_shape)} is sent as {shape[1]}x{shape[0]}")
    h, w, c = (int(v) for v in image_shape)
    if c % 3 == 0 and c > 3:
        pixels = np.concatenate(np.split(pixels, c // 3, axis=0), axis=2)
    elif c not in (1, 3, 4):
        pixels = np.stack(np.split(pixels, c, axis=0), axis=2)
    return np.ascontiguousarray(pixels).reshape(-1)


def vector_part(state, image_shape: tuple) -> np.ndarray:
    """What follows the pixels of a state (the values an EnvObservation carries on an image task)."""
    return np.asarray(state).reshape(-1)[math.prod(int(v) for v in image_shape):]
