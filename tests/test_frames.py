"""Rendered frames (nmrm_ros.tasks.frames): env_sim render:=true publishes each rendered step as a
standard sensor_msgs/CompressedImage on nmrm/frame, recorded in the bag like every other topic and
read back with its episode and step; encoding keeps frames small."""

import io

import numpy as np
import pytest
from PIL import Image

from nmrm_ros.testing.graph import finish, start
from nmrm_ros.bags import iter_decoded
from nmrm_ros.tasks.frames import encode_frame, frame_id, parse_frame_id


def test_frames_are_encoded_small_and_name_their_step():
    rgb = np.random.default_rng(0).integers(0, 255, (400, 600, 3), dtype=np.uint8)
    jpeg = Image.open(io.BytesIO(encode_frame(rgb, width=240)))
    assert (jpeg.format, jpeg.size) == ("JPEG", (240, 160))
    png = Image.open(io.BytesIO(encode_frame(rgb[:50, :100], width=240, fmt="png")))
    assert (png.format, png.size) == ("PNG", (100, 50))  # never scaled up
    assert parse_frame_id(frame_id(12, 7)) == (12, 7) and parse_frame_id("map") is None
    with pytest.raises(ValueError, match="not an RGB image"):
        encode_frame(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="frame format must be one of jpeg, png"):
        encode_frame(rgb, fmt="gif")


def test_rendered_frames_are_recorded_and_read_back(ros_domain, tmp_path):
    bag = tmp_path / "bag"
    recorder = start("recorder", output=bag, exit_with_upstream=True)
    agent = start("agent", task="gym:CartPole-v1", observe="observation", exit_with_upstream=True)
    sim = start("env_sim", task="gym:CartPole-v1", episodes=3, render=True, render_every=3,
                wait_for_nodes="[recorder, agent]", wait_for_subscribers=2)
    code, out = finish(sim, 90)
    assert code == 0 and "frame(s)" in out, out
    for proc in (agent, recorder):
        code, rest = finish(proc, 60)
        assert code == 0, rest
    observations, frames = {}, {}
    for topic, _, _, m in iter_decoded(bag):
        if topic == "/nmrm/observation":
            observations[(m.episode, m.step)] = (m.header.stamp.sec, m.header.stamp.nanosec, m.truncated or m.terminated)
        elif topic == "/nmrm/frame":
            frames[parse_frame_id(m.header.frame_id)] = (m.header.stamp.sec, m.header.stamp.nanosec, m.format,
                                                       Image.open(io.BytesIO(bytes(m.data))).size)
    finals = {e: t for (e, t), (_, _, last) in observations.items() if last}
    assert len(finals) == 3
    want = {(e, t) for (e, t) in observations if t % 3 == 0 or t == finals[e]}
    assert set(frames) == want
    for where, (sec, nsec, fmt, size) in frames.items():
        assert (sec, nsec) == observations[where][:2] and fmt == "jpeg" and size[0] == 240
