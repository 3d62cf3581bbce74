"""A LeRobot camera stream: the frames of consecutive episodes in one MP4 file (PyAV).

    with VideoWriter(path, fps=10, codec="h264") as video:
        start_s, end_s = video.add_episode(frames)      # (N, H, W, 3) uint8; the episode's times in the file
    for t, rgb in read_frames(path): ...               # (seconds, (H, W, 3) uint8), in order

Constant frame rate: frame k of the file is shown at k / fps, so an episode's frame j is at
`from_timestamp + j / fps`, as LeRobot's decoder looks it up (to within 1e-4 s). H.264 (libx264,
yuv420p, a key frame every 2 frames as LeRobot's encoder uses for fast seeking) is the default:
every decoder reads it; "av1" (libsvtav1, LeRobot's own default) is smaller. yuv420p needs even
sizes: an odd last row or column is cut off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .format import LeRobotError

#: codec name -> (PyAV encoder, options)
CODECS = {"h264": ("libx264", {"crf": "23", "g": "2", "preset": "veryfast"}),
          "av1": ("libsvtav1", {"crf": "30", "g": "2", "preset": "12"})}


class VideoWriter:
    """One MP4 file of one camera, episodes appended in order."""

    def __init__(self, path: str | Path, fps: int, codec: str = "h264") -> None:
        import av

        if codec not in CODECS:
            raise LeRobotError(f"video codec must be one of {', '.join(CODECS)}, got {codec!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fps = int(fps)
        self.codec = codec
        self.frames = 0  # frames written so far
        self.size: tuple | None = None  # (H, W) of every frame
        self._container = av.open(str(self.path), "w", format="mp4")
        self._stream = None

    def _open_stream(self, height: int, width: int) -> None:
        encoder, options = CODECS[self.codec]
        self._stream = self._container.add_stream(encoder, rate=self.fps)
        self._stream.width, self._stream.height = width, height
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = dict(options)

    def add_episode(self, frames: np.ndarray) -> tuple[float, float]:
        """Append an episode's frames (N, H, W, 3) uint8; returns (from_timestamp, to_timestamp)
        in seconds within this file."""
        import av

        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
            raise LeRobotError(f"frames must be (N, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
        h, w = frames.shape[1] // 2 * 2, frames.shape[2] // 2 * 2
        if self.size is None:
            if h < 2 or w < 2:
                self.close()
                raise LeRobotError(f"frames of {frames.shape[1]}x{frames.shape[2]} pixels are too small for a video")
            self.size = (h, w)
            try:
                self._open_stream(h, w)
            except Exception as exc:  # noqa: BLE001 - e.g. an encoder this PyAV build lacks
                self._stream = None
                self.close()
                raise LeRobotError(f"cannot encode {self.codec} video here: {exc}") from None
        elif self.size != (h, w):
            raise LeRobotError(f"frames of {frames.shape[1]}x{frames.shape[2]} pixels in a video of "
                               f"{self.size[0]}x{self.size[1]}: every frame of a camera must have one size")
        start = self.frames
        for rgb in frames[:, :h, :w]:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts = self.frames
            for packet in self._stream.encode(frame):
                self._container.mux(packet)
            self.frames += 1
        return start / self.fps, self.frames / self.fps

    def bytes(self) -> int:
        """Bytes in the file so far (what the muxer has written)."""
        return self.path.stat().st_size if self.path.exists() else 0

    def close(self) -> None:
        if self._container is None:
            return
        try:
            if self._stream is not None:
                for packet in self._stream.encode():
                    self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_frames(path: str | Path):
    """(time s, (H, W, 3) uint8) of every frame of an MP4 file's first video stream, in order;
    LeRobotError (one line) for a missing or undecodable file."""
    import av

    path = Path(path)
    if not path.is_file():
        raise LeRobotError(f"{path}: missing")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise LeRobotError(f"{path}: no video stream")
            stream = container.streams.video[0]
            for frame in container.decode(stream):
                t = float(frame.pts * stream.time_base) if frame.pts is not None else float(frame.time)
                yield t, frame.to_ndarray(format="rgb24")
    except av.FFmpegError as exc:
        raise LeRobotError(f"{path}: not a readable video ({exc})") from None


def video_info(path: str | Path, fps: int) -> dict:
    """The `info` of a video feature in meta/info.json, from its first file (as LeRobot's
    `get_video_info`)."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return {"video.height": int(stream.height), "video.width": int(stream.width),
                "video.codec": stream.codec_context.name, "video.pix_fmt": stream.codec_context.pix_fmt or "yuv420p",
                "video.is_depth_map": False, "video.fps": int(fps), "video.channels": 3, "has_audio": False}
