"""An image task's observations on the graph: the pixels as an image beside the step messages.

On an image task the pixels of a state travel apart from it (`nmrm_ros.tasks.image_states`): an
EnvObservation (or a RewardStep) of step (e, t) carries the vector part of the state, and a
`sensor_msgs/CompressedImage` on `nmrm/observation_image` whose `header.frame_id` is
`nmrm_episode_<e>_step_<t>` (`tasks.frames.frame_id`) carries the pixels. A consumer gives both
to an `ImagePairing` (plain Python, duck-typed messages), which calls `deliver(msg)` once both of a step are in, with the pixels put
back in front of each of `fields` (`state`, and a RewardStep's `augmented_state`): the consumer
then sees the whole state, as without images. The two topics have no order between them, so the
message may come before its image or after it.

A message whose first field already has the whole state's size (a publisher that sends the
pixels as floats, e.g. a bag recorded before images travelled apart) is delivered as it is, and
so is one of any other size (the consumer's own checks say what is wrong with it). Bounded: the
last `capacity` images are kept (a re-published observation finds its image again) and at most
`capacity` messages wait for theirs; beyond that the oldest waiting one is dropped (`unpaired`),
as the consumer's episode rules would drop a lost observation. An image that cannot be decoded
or names no step is counted (`bad_images`, `last_error`) and never delivered.

A publisher of observations (env_sim, observation_bridge) sends each state through an
`ObservationImagePublisher`: it publishes the pixels and returns the rest for the EnvObservation.
"""

from __future__ import annotations

import array
import math
import threading
from collections import OrderedDict
from typing import Callable

import numpy as np

from ..tasks.frames import parse_frame_id
from ..tasks.image_states import decode_image_state


class ImagePairing:
    """image_shape: the task's (H, W, C); state_size: the whole state's size (pixels + vector);
    deliver(msg): called with each message whose image is in (from the thread that brought the
    second of the two); fields: the float32[] fields of the message the pixels lead; on_error(why):
    called for each image refused (e.g. to log it)."""

    def __init__(self, image_shape: tuple, state_size: int, deliver: Callable, fields: tuple = ("state",),
                 capacity: int = 256, on_error: Callable | None = None) -> None:
        self.image_shape = tuple(int(v) for v in image_shape)
        self.pixels = math.prod(self.image_shape)
        self.vector_size = int(state_size) - self.pixels
        self.deliver, self.fields, self.capacity, self.on_error = deliver, tuple(fields), int(capacity), on_error
        self.images: OrderedDict = OrderedDict()   # (e, t) -> pixels as float32 (H*W*C,)
        self.waiting: OrderedDict = OrderedDict()  # (e, t) -> [messages waiting for that image]
        self.lock = threading.Lock()
        #: messages dropped for want of their image; images that could not be used; why the last one
        self.unpaired = 0
        self.bad_images = 0
        self.last_error = ""

    def on_image(self, msg) -> None:
        """A CompressedImage of `nmrm/observation_image`."""
        key = parse_frame_id(msg.header.frame_id)
        try:
            if key is None:
                raise ValueError(f"observation image with frame_id {msg.header.frame_id!r} names no step "
                                 f"(nmrm_episode_<e>_step_<t>)")
            pixels = decode_image_state(msg.data, self.image_shape).astype(np.float32)
        except ValueError as exc:
            with self.lock:
                self.bad_images += 1
                self.last_error = str(exc)
            if self.on_error is not None:
                self.on_error(str(exc))
            return
        with self.lock:
            self.images[key] = pixels
            self.images.move_to_end(key)
            while len(self.images) > self.capacity:
                self.images.popitem(last=False)
            ready = self.waiting.pop(key, [])
        for m in ready:
            self.deliver(self._joined(m, pixels))

    def on_message(self, msg) -> None:
        """An EnvObservation / RewardStep of the image task."""
        if len(getattr(msg, self.fields[0])) != self.vector_size:
            self.deliver(msg)  # the pixels already in it, or a size the consumer will refuse
            return
        key = (int(msg.episode), int(msg.step))
        with self.lock:
            pixels = self.images.get(key)
            if pixels is None:
                self.waiting.setdefault(key, []).append(msg)
                while len(self.waiting) > self.capacity:
                    self.unpaired += len(self.waiting.popitem(last=False)[1])
                return
        self.deliver(self._joined(msg, pixels))

    def _joined(self, msg, pixels: np.ndarray):
        for name in self.fields:
            rest = np.asarray(getattr(msg, name), dtype=np.float32)
            setattr(msg, name, array.array("f", np.concatenate([pixels, rest]).tobytes()))
        return msg


class ObservationImagePublisher:
    """The observation images of `node`'s image task (`info.image_shape`) on `topic`."""

    def __init__(self, node, info, topic: str) -> None:
        from sensor_msgs.msg import CompressedImage

        from .topics import STEP_QOS

        self.image_shape, self.message = tuple(info.image_shape), CompressedImage
        self.pub = node.create_publisher(CompressedImage, topic, STEP_QOS)

    def publish(self, state, episode: int, step: int, stamp) -> np.ndarray:
        """Publish the pixels of `state` (step `step` of `episode`, header.stamp `stamp`) as a PNG;
        the rest of the state, for the EnvObservation. ValueError if they are not an image's."""
        from ..tasks.frames import frame_id
        from ..tasks.image_states import IMAGE_STATE_FORMAT, encode_image_state, vector_part

        image = self.message(format=IMAGE_STATE_FORMAT, data=encode_image_state(state, self.image_shape))
        image.header.stamp, image.header.frame_id = stamp, frame_id(episode, step)
        self.pub.publish(image)
        return vector_part(state, self.image_shape)
