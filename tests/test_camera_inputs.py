"""A robot's cameras as a task's image state: sensor_msgs Image (every encoding read) and
CompressedImage decoded and resized, the robot spec's camera and privileged inputs, and the
observation bridge as a real process turning a camera and a motion-capture pose into pixel-task
observations with their privileged state."""

from __future__ import annotations

import io
import signal
import time

import numpy as np
import pytest

from nmrm_ros.ros.image_messages import compressed_pixels, image_pixels, image_reader, to_channels
from nmrm_ros.ros.robot_spec import parse_robot_spec
from nmrm_ros.tasks.frames import parse_frame_id


def _picture(h: int = 48, w: int = 64) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 3, y * 5, (x + y) % 256], -1).astype(np.uint8)


def _image(pixels: np.ndarray, encoding: str, pad: int = 0, bigendian: bool = False):
    from sensor_msgs.msg import Image

    h, w = pixels.shape[:2]
    rows = pixels.reshape(h, -1)
    rows = np.concatenate([rows, np.zeros((h, pad), np.uint8)], axis=1)
    return Image(height=h, width=w, encoding=encoding, is_bigendian=bigendian, step=rows.shape[1],
                 data=rows.tobytes())


def _compressed(pixels: np.ndarray, fmt: str = "png"):
    from PIL import Image as PILImage
    from sensor_msgs.msg import CompressedImage

    buf = io.BytesIO()
    PILImage.fromarray(pixels).save(buf, format=fmt.upper())
    return CompressedImage(format=fmt, data=buf.getvalue())


def test_image_encodings_are_read_as_rgb_or_grey():
    rgb = _picture()
    np.testing.assert_array_equal(image_pixels(_image(rgb, "rgb8")), rgb)
    np.testing.assert_array_equal(image_pixels(_image(rgb[..., ::-1].copy(), "bgr8", pad=8)), rgb)  # row padding
    np.testing.assert_array_equal(image_pixels(_image(rgb[..., ::-1].copy(), "8UC3")), rgb)  # OpenCV's order
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 7, np.uint8)], -1)
    np.testing.assert_array_equal(to_channels(image_pixels(_image(rgba, "rgba8")), 3), rgb)
    bgra = np.concatenate([rgb[..., ::-1], np.full(rgb.shape[:2] + (1,), 7, np.uint8)], -1)
    np.testing.assert_array_equal(to_channels(image_pixels(_image(bgra, "bgra8")), 3), rgb)
    grey = rgb[..., 1]
    wide = grey.astype(np.uint16) * 256 + 17  # 16-bit: the top byte is the grey value
    little = wide.astype("<u2").view(np.uint8).reshape(grey.shape[0], -1)
    big = wide.astype(">u2").view(np.uint8).reshape(grey.shape[0], -1)
    for data, encoding, bigendian in ((little, "mono16", False), (big, "16UC1", True)):
        msg = _image(data, encoding, bigendian=bigendian)
        msg.width = grey.shape[1]
        np.testing.assert_array_equal(image_pixels(msg)[..., 0], grey)
    np.testing.assert_array_equal(image_pixels(_image(grey[..., None], "mono8"))[..., 0], grey)
    assert to_channels(image_pixels(_image(grey[..., None], "mono8")), 3).shape == grey.shape + (3,)
    with pytest.raises(ValueError, match="encoding 'yuv422' is not read"):
        image_pixels(_image(rgb, "yuv422"))
    short = _image(rgb, "rgb8")
    short.data = short.data[:100]
    with pytest.raises(ValueError, match="needs 9216 bytes, has 100"):
        image_pixels(short)


def test_compressed_frames_are_decoded_resized_and_bad_data_is_an_error():
    rgb = _picture()
    np.testing.assert_array_equal(compressed_pixels(_compressed(rgb)), rgb)  # PNG: lossless
    assert np.abs(compressed_pixels(_compressed(rgb, "jpeg")).astype(int) - rgb).mean() < 4
    read = image_reader("sensor_msgs/msg/CompressedImage", (24, 32))
    small = read(_compressed(rgb))
    assert small.shape == (24, 32, 3) and small.dtype == np.uint8
    assert abs(int(small[12, 16, 0]) - int(rgb[24, 32, 0])) <= 6  # bilinear, halved
    grey = image_reader("sensor_msgs/Image", (48, 64), channels=1)(_image(rgb, "rgb8"))
    expected = np.rint(rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32))
    assert grey.shape == (48, 64, 1) and np.abs(grey[..., 0] - expected).max() <= 1
    from sensor_msgs.msg import CompressedImage

    with pytest.raises(ValueError, match=r"compressed image \(jpeg\) cannot be decoded"):
        compressed_pixels(CompressedImage(format="jpeg", data=b"not an image"))


def _publish_until_done(bridge, capture, publish, timeout: float = 60.0) -> tuple:
    """Call `publish()` every 20 ms (spinning the capture) until the bridge process exits, at most
    `timeout` s; its (exit code, output)."""
    from nmrm_ros.testing.graph import finish

    deadline = time.monotonic() + timeout
    while bridge.poll() is None and time.monotonic() < deadline:
        publish()
        capture.spin_for(0.02)
    return finish(bridge)


CAMERA_SPEC = """
observation:
  rate: 20.0
  stale_after: 0.5
  inputs:
    - {topic: /camera/compressed, type: sensor_msgs/msg/CompressedImage, qos: sensor_data, image: 32x32}
    - {topic: /mocap, type: geometry_msgs/msg/PoseStamped, fields: [pose.position.x, pose.position.y], privileged: true}
episode:
  max_steps: 5
action:
  discrete: {0: {linear.x: 0.1}}
"""


def test_the_robot_spec_takes_cameras_and_privileged_inputs():
    spec = parse_robot_spec(CAMERA_SPEC)
    assert spec.image_shape == (32, 32, 3) and [i.privileged for i in spec.inputs] == [False, True]
    two = CAMERA_SPEC.replace("    - {topic: /mocap", "    - {topic: /ir, type: sensor_msgs/msg/Image, image: 32x32, "
                                                     "channels: 1}\n    - {topic: /mocap")
    assert parse_robot_spec(two).image_shape == (32, 32, 4)
    camera = "    - {topic: /camera/compressed, type: sensor_msgs/msg/CompressedImage, qos: sensor_data, image: 32x32}"
    for replacement, message in (
            (camera.replace("image: 32x32", "image: 32"), r"inputs\[0\].image must be the size HxW"),
            (camera.replace("image: 32x32", "image: 0x32"), r"inputs\[0\].image must be the size HxW"),
            (camera.replace("image: 32x32", "image: 32x32, channels: 4"), r"channels must be 3 \(RGB\) or 1"),
            (camera.replace("image: 32x32", "image: 32x32, fields: [data]"), "a camera input takes topic"),
            (camera.replace("image: 32x32", "image: 32x32, privileged: true"), "a camera cannot be privileged"),
            (camera + "\n    - {topic: /b, type: sensor_msgs/msg/Image, image: 16x16}", "share one image size"),
    ):
        with pytest.raises(ValueError, match=message):
            parse_robot_spec(CAMERA_SPEC.replace(camera, replacement))
    with pytest.raises(ValueError, match="privileged must be true or false"):
        parse_robot_spec(CAMERA_SPEC.replace("privileged: true", "privileged: 3"))
    with pytest.raises(ValueError, match="every input is privileged"):
        parse_robot_spec(CAMERA_SPEC.replace(camera + "\n", ""))
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['image'\]"):
        parse_robot_spec(CAMERA_SPEC.replace("fields: [pose.position.x, pose.position.y],",
                                             "fields: [pose.position.x, pose.position.y], image: 8x8,"))


def test_a_camera_robot_makes_pixel_task_observations_with_their_privileged_state(ros_domain, tmp_path):
    """observation_bridge (a real process) with a CompressedImage camera (PNG 64x64, resized to
    32x32) and a privileged PoseStamped: key_pixels observations whose state is the resized frame
    (sent as the observation image beside them) and whose privileged state is the pose; the
    recorder's bag reads back the same states; a spec whose cameras do not make the task's image is a
    one-line error."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage

    from nmrm_ros.testing.graph import Capture, finish, start

    (tmp_path / "camera.yaml").write_text(CAMERA_SPEC)
    frame = _picture(64, 64)
    expected = image_reader("sensor_msgs/msg/CompressedImage", (32, 32))(_compressed(frame)).reshape(-1)
    capture = Capture()
    recorder = start("recorder", output=str(tmp_path / "bag"), exit_with_upstream=True)
    bridge = start("observation_bridge", spec=tmp_path / "camera.yaml", task="key_pixels", episodes=1,
                   wait_for_subscribers=2)
    try:
        camera = capture.node.create_publisher(CompressedImage, "/camera/compressed", qos_profile_sensor_data)
        mocap = capture.node.create_publisher(PoseStamped, "/mocap", 10)
        assert capture.spin_until(lambda: camera.get_subscription_count() >= 1 and mocap.get_subscription_count() >= 1, 30)
        pose = PoseStamped()
        pose.pose.position.x, pose.pose.position.y = 0.25, 0.75
        message = _compressed(frame)
        code, out = _publish_until_done(bridge, capture, lambda: (camera.publish(message), mocap.publish(pose)))
    finally:
        if bridge.poll() is None:
            bridge.send_signal(signal.SIGINT)
        capture.close()
        recorded = finish(recorder)
    # the pixels travel as a PNG on nmrm/observation_image, the observation's state is what follows them
    assert all(len(m.state) == 0 for m in capture.msgs["observation"])
    assert sorted(parse_frame_id(m.header.frame_id) for m in capture.msgs["observation_image"]) == \
        [(0, t) for t in range(6)]
    obs = capture.joined("observation", "key_pixels")
    assert code == 0 and [m.step for m in obs] == list(range(6)) and obs[-1].truncated, out
    for m in obs:
        assert m.task == "key_pixels" and len(m.state) == 32 * 32 * 3
        np.testing.assert_array_equal(np.asarray(m.state), expected)
        assert list(m.privileged) == pytest.approx([0.25, 0.75])
    from nmrm_ros.interpret.episode_view import read_episodes

    assert recorded[0] == 0, recorded[1]
    episode = read_episodes(tmp_path / "bag")[("", 0)]
    np.testing.assert_array_equal(episode.states, np.stack([expected] * 5).astype(np.float32))
    np.testing.assert_allclose(episode.privileged, [[0.25, 0.75]] * 5)
    # the key task has no image state: a spec with a camera is refused at start, in one line
    bridge = start("observation_bridge", spec=tmp_path / "camera.yaml", task="key")
    code, out = finish(bridge)
    assert code == 2 and "the spec's cameras make 32x32x3; task key has no image in its state" in out, out


def test_a_camera_robot_with_the_tasks_frozen_encoder_makes_its_features(ros_domain, tmp_path, monkeypatch):
    """observation_bridge (a real process) for a task spec with a user's frozen encoder
    (`encoder=`, `encoder_weights=`): each observation's state is the encoder's features of the
    camera's resized frame, as the task's own env gives them; a camera of another size than the
    encoder reads is a one-line error at start."""
    import os
    import textwrap

    import torch
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage

    from nmrm_ros.tasks.gym_task import task_encoder
    from nmrm_ros.testing.graph import Capture, finish, start

    (tmp_path / "robot_room.py").write_text(textwrap.dedent('''
        import gymnasium as gym
        import numpy as np

        class RobotRoom(gym.Env):
            """The robot's simulator: a 32 x 32 camera image."""
            observation_space = gym.spaces.Box(0, 255, (32, 32, 3), np.uint8)
            action_space = gym.spaces.Discrete(2)
            def reset(self, *, seed=None, options=None):
                super().reset(seed=seed)
                return np.zeros((32, 32, 3), np.uint8), {}
            def step(self, action):
                return np.zeros((32, 32, 3), np.uint8), 0.0, False, False, {}
    '''))
    (tmp_path / "robot_encoder.py").write_text(textwrap.dedent('''
        import torch

        class Encoder(torch.nn.Module):
            def __init__(self):
                super().__init__()
                self.conv = torch.nn.Conv2d(3, 2, 8, stride=8)
            def forward(self, x):
                return torch.tanh(self.conv(x)).flatten(1)
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")])))
    import robot_encoder

    torch.manual_seed(3)
    torch.save(robot_encoder.Encoder().state_dict(), tmp_path / "enc.pt")
    task = f"robot_room:RobotRoom,max_steps=50,encoder=robot_encoder:Encoder,encoder_weights={tmp_path / 'enc.pt'}"
    spec = CAMERA_SPEC.replace("    - {topic: /mocap, type: geometry_msgs/msg/PoseStamped, fields: [pose.position.x, "
                               "pose.position.y], privileged: true}\n", "")
    (tmp_path / "camera.yaml").write_text(spec)
    frame = _picture(64, 64)
    pixels = image_reader("sensor_msgs/msg/CompressedImage", (32, 32))(_compressed(frame))
    expected = task_encoder(task, (32, 32, 3))(pixels)
    assert expected.shape == (2 * 4 * 4,)
    capture = Capture()
    bridge = start("observation_bridge", spec=tmp_path / "camera.yaml", task=task, episodes=1, wait_for_subscribers=1)
    try:
        camera = capture.node.create_publisher(CompressedImage, "/camera/compressed", qos_profile_sensor_data)
        assert capture.spin_until(lambda: camera.get_subscription_count() >= 1, 30)
        message = _compressed(frame)
        code, out = _publish_until_done(bridge, capture, lambda: camera.publish(message))
    finally:
        if bridge.poll() is None:
            bridge.send_signal(signal.SIGINT)
        capture.close()
    obs = capture.msgs["observation"]
    assert code == 0 and [m.step for m in obs] == list(range(6)), out
    for m in obs:
        np.testing.assert_allclose(np.asarray(m.state), expected, atol=1e-6)
    (tmp_path / "small.yaml").write_text(spec.replace("image: 32x32", "image: 16x16"))
    code, out = finish(start("observation_bridge", spec=tmp_path / "small.yaml", task=task))
    assert code == 2 and "the spec's cameras make 16x16x3; task" in out and "encoder reads 32x32x3" in out, out
    assert "Traceback" not in out
