"""Writing rosbag2-compatible MCAP bags: a directory with `metadata.yaml` and one `<name>_0.mcap`.

The MCAP file follows the ros2 profile (CDR messages, ros2msg schemas embedded, zstd-compressed
chunks, summary and indexes) and carries rosbag2's own metadata record, so `ros2 bag info/play`,
Foxglove, the `mcap` CLI and the `rosbags` library read it. Messages go in either as CDR bytes
(`write_cdr`: what a raw rclpy subscription delivers, no re-encoding) or as plain dicts
(`write_dict`: encoded by mcap_ros2's CDR encoder from the schema; no ROS needed).

`flush()` ends the chunk in progress and pushes the file to disk: after a hard kill, everything
written before the last flush is recoverable with `nmrm bag repair`.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from .schemas import message_definition, short_name, type_hash

METADATA_VERSION = 9
#: QoS the nmrm topics are offered with (see nmrm_ros.ros.topics), in rosbag2 v9 form.
OFFERED_QOS = [{
    "history": "keep_all", "depth": 0, "reliability": "reliable", "durability": "volatile",
    "deadline": {"sec": 0, "nsec": 0}, "lifespan": {"sec": 0, "nsec": 0},
    "liveliness": "automatic", "liveliness_lease_duration": {"sec": 0, "nsec": 0},
    "avoid_ros_namespace_conventions": False,
}]


class BagWriter:
    """Write one bag directory. Use as a context manager, or call `close()` (idempotent)."""

    def __init__(self, path: str | Path, chunk_size: int = 256 * 1024,
                 compression: str = "zstd", overwrite: bool = False,
                 file_name: str | None = None) -> None:
        self.path = Path(path)
        if self.path.exists() and any(self.path.iterdir()) and not overwrite:
            raise FileExistsError(f"bag directory {self.path} exists and is not empty")
        self.created_dir = not self.path.exists()  # so a discarded bag leaves no directory behind
        self.path.mkdir(parents=True, exist_ok=True)
        self.file_name = file_name or f"{self.path.name}_0.mcap"
        self._file = open(self.path / self.file_name, "wb")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp[compression])
        self._writer.start(profile="ros2", library="nmrm_ros")
        self._schemas: dict = {}
        self._channels: dict = {}  # topic -> (channel id, type name)
        self._encoders: dict = {}
        self.counts: dict = {}
        self._sequence = 0
        self._flushed_at = 0  # self._sequence at the last flush
        self.start_ns: int | None = None
        self.end_ns = 0
        self.closed = False

    # -- registration ----------------------------------------------------------------------------
    def add_topic(self, topic: str, type_name: str, definition: bytes | None = None) -> int:
        """Register `topic` with `type_name` (idempotent); returns the channel id. definition: the
        schema text the messages were written with (a repaired bag's own: an older definition of
        the type), default today's."""
        if topic in self._channels:
            cid, known = self._channels[topic]
            if known != type_name:
                raise ValueError(f"topic {topic} already has type {known}, not {type_name}")
            return cid
        short_name(type_name)  # validates the type
        text = message_definition(type_name).encode() if definition is None else bytes(definition)
        if (type_name, text) not in self._schemas:
            self._schemas[(type_name, text)] = self._writer.register_schema(type_name, "ros2msg", text)
        qos = yaml.safe_dump(OFFERED_QOS, default_flow_style=False)
        cid = self._writer.register_channel(topic, "cdr", self._schemas[(type_name, text)],
                                            {"offered_qos_profiles": qos,
                                             "topic_type_hash": type_hash(type_name)})
        self._channels[topic] = (cid, type_name)
        self.counts[topic] = 0
        return cid

    # -- messages ----------------------------------------------------------------------------------
    def write_cdr(self, topic: str, type_name: str, data: bytes, log_time_ns: int,
                  publish_time_ns: int | None = None, definition: bytes | None = None) -> None:
        """Append one CDR-serialised message (written with schema text `definition`, default
        today's: `add_topic`)."""
        if self.closed:
            raise ValueError(f"bag {self.path} is closed")
        cid = self.add_topic(topic, type_name, definition)
        self._writer.add_message(cid, log_time=int(log_time_ns), data=bytes(data),
                                 publish_time=int(publish_time_ns if publish_time_ns is not None else log_time_ns),
                                 sequence=self._sequence)
        self._sequence += 1
        self.counts[topic] += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = max(self.end_ns, log_time_ns)

    def write_dict(self, topic: str, type_name: str, message: dict, log_time_ns: int) -> None:
        """Encode a message given as a dict of its fields (all fields required) and append it."""
        self.write_cdr(topic, type_name, self.encode(type_name, message), log_time_ns)

    def encode(self, type_name: str, message: dict) -> bytes:
        from mcap_ros2._dynamic import serialize_dynamic

        if type_name not in self._encoders:
            self._encoders[type_name] = serialize_dynamic(type_name, message_definition(type_name))[type_name]
        return self._encoders[type_name](message)

    def flush(self) -> None:
        """End the chunk in progress and push the bag to the disk (fsync), so nothing written so far
        is lost on a hard kill (smaller chunks compress a little less). A no-op when nothing was
        written since the last flush."""
        if self._sequence == self._flushed_at:
            return
        self._writer.flush()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._flushed_at = self._sequence

    # -- closing ---------------------------------------------------------------------------------
    def metadata(self) -> dict:
        count = sum(self.counts.values())
        start = self.start_ns or 0
        duration = max(0, self.end_ns - start)
        return {"rosbag2_bagfile_information": {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.file_name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": topic, "type": type_name, "serialization_format": "cdr",
                                    "offered_qos_profiles": OFFERED_QOS,
                                    "type_description_hash": type_hash(type_name)},
                 "message_count": self.counts[topic]}
                for topic, (_, type_name) in self._channels.items()],
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": self.file_name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": None,
            "ros_distro": "jazzy",
        }}

    def close(self) -> None:
        """Finish the MCAP (summary, indexes, rosbag2 metadata record) and write metadata.yaml."""
        if self.closed:
            return
        self.closed = True
        info = self.metadata()
        self._writer.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(
            info["rosbag2_bagfile_information"], sort_keys=False)})
        self._writer.finish()
        self._file.close()
        write_metadata_yaml(self.path, info)

    def discard(self) -> None:
        """Close and delete this bag (for one that recorded nothing: leave no debris): its files,
        and its directory if this writer created it and nothing else is in it."""
        self.close()
        for name in (self.file_name, "metadata.yaml"):
            (self.path / name).unlink(missing_ok=True)
        if self.created_dir and self.path.is_dir() and not any(self.path.iterdir()):
            self.path.rmdir()

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_metadata_yaml(path: Path, info: dict) -> None:
    """Write metadata.yaml atomically (a reader never sees half a file)."""
    tmp = path / "metadata.yaml.tmp"
    tmp.write_text(yaml.safe_dump(info, sort_keys=False))
    tmp.replace(path / "metadata.yaml")


def now_ns() -> int:
    return time.time_ns()
