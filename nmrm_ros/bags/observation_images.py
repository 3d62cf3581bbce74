"""An image task's observation images in a bag, put back in front of its states.

A bag records an image task as the graph sends it (`nmrm_ros.tasks.image_states`): each
EnvObservation holds the state's values after the pixels, and the pixels are a PNG
`sensor_msgs/CompressedImage` on `<source>/nmrm/observation_image` whose frame_id names the step.
Every reader of a bag's states (datasets, `nmrm explain`, the LeRobot export) collects them with
`BagImages.take` while it reads and asks `whole_state` for each observation. A bag recorded
before the pixels travelled apart has whole states already: they are kept as they are.
"""

from __future__ import annotations

import numpy as np

from ..tasks.frames import parse_frame_id
from ..tasks.image_states import decode_image_state
from .schemas import IMAGE_TOPIC, TOPIC_TYPES

IMAGE_TYPE = TOPIC_TYPES[IMAGE_TOPIC]


class BagImages:
    """The observation images read so far: (source, episode, step) -> PNG bytes."""

    def __init__(self) -> None:
        self.data: dict = {}

    def take(self, topic: str, type_name: str, msg) -> bool:
        """Keep `msg` if it is an observation image (one naming its step); whether it was one."""
        if type_name != IMAGE_TYPE or not topic.endswith(IMAGE_TOPIC):
            return False
        step = parse_frame_id(msg.header.frame_id)
        if step is not None:
            self.data[(topic[: -len(IMAGE_TOPIC)], *step)] = bytes(msg.data)
        return True

    def whole_state(self, source: str, msg, info) -> np.ndarray:
        """The state (float32) of EnvObservation `msg` of topic namespace `source`: on an image
        task (`info`) whose message carries only the values after the pixels, the pixels of its
        observation image in front; else its state as it is. ValueError (one line) if the image
        is missing or cannot be decoded."""
        state = np.asarray(msg.state, np.float32)
        if not info.image_shape or state.size != info.state_size - info.image_values:
            return state
        data = self.data.get((source, int(msg.episode), int(msg.step)))
        if data is None:
            raise ValueError(f"episode {msg.episode} step {msg.step} has no observation image")
        return np.concatenate([decode_image_state(data, info.image_shape).astype(np.float32), state])
