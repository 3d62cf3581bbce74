"""Camera messages as pixels: `sensor_msgs/Image` and `sensor_msgs/CompressedImage` -> (H, W, C) uint8.

    read = image_reader("sensor_msgs/msg/CompressedImage", size=(64, 64), channels=3)
    pixels = read(msg)          # (64, 64, 3) uint8, resized bilinearly; ValueError if undecodable

Image encodings read: rgb8, bgr8, rgba8, bgra8 (alpha dropped), mono8, 8UC1, 8UC3 (as bgr8, OpenCV's
order), mono16 / 16UC1 (the top 8 bits), with any row stride (`step`) and either byte order.
CompressedImage: whatever Pillow decodes (JPEG, PNG, ...). `channels` 3 gives RGB (a mono camera
is repeated), 1 gives luminance (ITU-R 601, Pillow's "L"). The robot spec's camera inputs use it
(`robot_spec`: `image: HxW`), so that a robot's camera is a task's image state (`TaskInfo.image_shape`).
"""

from __future__ import annotations

import io
from typing import Callable

import numpy as np

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
#: encoding -> (channels, bytes per channel, channel order as read)
ENCODINGS = {"rgb8": (3, 1, "RGB"), "bgr8": (3, 1, "BGR"), "rgba8": (4, 1, "RGBA"), "bgra8": (4, 1, "BGRA"),
             "mono8": (1, 1, "L"), "8UC1": (1, 1, "L"), "8UC3": (3, 1, "BGR"), "mono16": (1, 2, "L"),
             "16UC1": (1, 2, "L")}


def is_image_type(type_name: str) -> bool:
    """Whether messages of `type_name` are camera images this module reads."""
    return type_name.replace("/msg/", "/") in {t.replace("/msg/", "/") for t in IMAGE_TYPES}


def image_pixels(msg) -> np.ndarray:
    """The pixels of a sensor_msgs Image (H, W, C) uint8 in RGB / RGBA / L order as its encoding
    says; ValueError for an encoding not in ENCODINGS or data of the wrong size."""
    encoding = str(msg.encoding)
    if encoding not in ENCODINGS:
        raise ValueError(f"image encoding {encoding!r} is not read (read: {', '.join(ENCODINGS)})")
    channels, depth, order = ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * depth
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if h < 1 or w < 1 or step < row or data.size < step * (h - 1) + row:
        raise ValueError(f"image {w}x{h} {encoding} with step {step} needs {step * (h - 1) + row} bytes, "
                         f"has {data.size}")
    rows = np.lib.stride_tricks.as_strided(data, shape=(h, row), strides=(step, 1), writeable=False)
    if depth == 2:
        high = 0 if msg.is_bigendian else 1  # the top 8 bits of each 16-bit value
        rows = rows[:, high::2]
    pixels = np.ascontiguousarray(rows).reshape(h, w, channels)
    if order.startswith("BGR"):
        pixels = pixels[..., [2, 1, 0] + ([3] if channels == 4 else [])]
    return pixels


def compressed_pixels(msg) -> np.ndarray:
    """The decoded pixels of a sensor_msgs CompressedImage (H, W, C) uint8, RGB or L; ValueError
    if Pillow cannot decode its data."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(bytes(msg.data))) as image:
            image = image.convert("L" if image.mode in ("L", "I", "I;16") else "RGB")
            return np.asarray(image)[..., None] if image.mode == "L" else np.asarray(image)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"compressed image ({msg.format or 'no format'}) cannot be decoded: {exc}") from None


def to_channels(pixels: np.ndarray, channels: int) -> np.ndarray:
    """(H, W, C) uint8 -> (H, W, channels): 3 = RGB (alpha dropped, a mono image repeated), 1 =
    luminance."""
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    rgb = pixels[..., :3] if pixels.shape[2] >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if channels == 3:
        return rgb
    if pixels.shape[2] == 1:
        return pixels
    luma = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.clip(np.rint(luma), 0, 255).astype(np.uint8)[..., None]


def image_reader(type_name: str, size: tuple, channels: int = 3) -> Callable:
    """msg -> (H, W, channels) uint8 of a camera message of `type_name` (IMAGE_TYPES), resized
    bilinearly to `size` (H, W)."""
    from ..tasks.gym_task import resize_image

    if not is_image_type(type_name):
        raise ValueError(f"{type_name} is not a camera image type ({', '.join(IMAGE_TYPES)})")
    decode = compressed_pixels if type_name.endswith("CompressedImage") else image_pixels
    return lambda msg: resize_image(to_channels(decode(msg), channels), size)
