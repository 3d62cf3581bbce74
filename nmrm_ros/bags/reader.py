"""Reading bags: a rosbag2 directory (metadata.yaml + .mcap files) or a bare .mcap file.

Every failure to read (missing file, not an MCAP, truncated, a chunk whose CRC or compression is
damaged, undecodable message) raises `BagError` with the path, where the damage is and what to do,
never a bare library exception. Chunk CRCs are validated on every read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader

from .errors import BagError


REPAIR_HINT = "if the recording was killed, `nmrm bag repair {path}` recovers what reached the disk"


@dataclass
class RawMessage:
    topic: str
    type_name: str
    log_time_ns: int
    data: bytes


def bag_files(path: str | Path) -> list:
    """The .mcap files of a bag directory (from metadata.yaml) or of a bare .mcap path."""
    path = Path(path)
    if path.is_file():
        if path.suffix != ".mcap":
            raise BagError(f"{path}: not an .mcap file")
        return [path]
    if not path.is_dir():
        raise BagError(f"no bag at {path}")
    meta = path / "metadata.yaml"
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            files = [path / f for f in info["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise BagError(f"{meta}: malformed rosbag2 metadata ({exc})") from None
        for f in files:
            if not f.is_file():
                raise BagError(f"{path}: metadata.yaml lists {f.name}, which is missing")
        return files
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise BagError(f"{path}: no metadata.yaml and no .mcap file")
    raise BagError(f"{path}: no metadata.yaml (the recording did not close); "
                   + REPAIR_HINT.format(path=path))


def _iter(path: str | Path, topics: list | None):
    """(schema, channel, message) records of every file of a bag, chunk CRCs checked; any damage
    -> BagError naming the file, the damaged chunk(s) and how many messages were read before."""
    for file in bag_files(path):
        n = 0
        try:
            with open(file, "rb") as f:
                for item in make_reader(f, validate_crcs=True).iter_messages(topics=topics,
                                                                             log_time_order=False):
                    n += 1
                    yield item
        except Exception as exc:  # noqa: BLE001 - mcap, zstandard, lz4, struct...: the file is damaged
            raise BagError(_damage(file, path, exc, n)) from None


def _damage(file: Path, path, exc: Exception, read: int) -> str:
    """One line: what is damaged in `file` and where, and what to do."""
    from .chunks import scan_chunks

    what = f"{type(exc).__name__}: {str(exc).strip()[:160]}"
    try:
        where = scan_chunks(file).describe()
    except Exception:  # noqa: BLE001 - the scan adds detail only
        where = "none found"
    return (f"{file}: damaged ({where if where != 'none found' else what}); "
            f"{read} message(s) read before it, none used; `nmrm bag repair {path}` rebuilds the bag "
            f"from every intact chunk")


def _to_current(schema, channel):
    """A converter of CDR messages written with `schema` to today's definition of the type (decode
    with the bag's schema, encode with today's; fields it lacks are empty), or None where the two
    are the same or the type is not one whose definition we carry."""
    from mcap_ros2._dynamic import serialize_dynamic
    from mcap_ros2.decoder import DecoderFactory

    from .schemas import message_definition

    try:
        today = message_definition(schema.name)
    except (OSError, ValueError, KeyError):  # not one of ours nor a standard type we write
        return None
    if today.encode() == bytes(schema.data):
        return None
    decode = DecoderFactory().decoder_for(channel.message_encoding, schema)
    encode = serialize_dynamic(schema.name, today)[schema.name]
    return lambda data: encode(decode(data))


def iter_raw(path: str | Path, topics: list | None = None, current: bool = False) -> Iterator[RawMessage]:
    """Every message of a bag as it was written (CDR bytes). current: a message written with an
    older definition of its type than today's (a bag recorded before a field was added) is
    re-encoded with today's, its new fields empty, so that today's subscribers can read it
    (replay); a BagError if it cannot be decoded."""
    converters: dict = {}
    for schema, channel, message in _iter(path, topics):
        data = message.data
        if current and schema is not None:
            key = (schema.name, bytes(schema.data))
            if key not in converters:
                converters[key] = _to_current(schema, channel)
            if converters[key] is not None:
                try:
                    data = converters[key](data)
                except Exception as exc:  # noqa: BLE001 - a message its own schema does not describe
                    raise BagError(f"{path}: cannot decode a {schema.name} message on {channel.topic} with "
                                   f"the bag's schema: {exc}") from None
        yield RawMessage(channel.topic, schema.name if schema else "", message.log_time, data)


def iter_decoded(path: str | Path, topics: list | None = None) -> Iterator[tuple]:
    """(topic, type name, log time ns, decoded message) for every message of a bag. Decoded
    messages are plain objects with the message's fields as attributes (mcap_ros2)."""
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    decoders: dict = {}
    for schema, channel, message in _iter(path, topics):
        if schema is None:
            raise BagError(f"{path}: channel {channel.topic} has no schema")
        try:
            if schema.name not in decoders:
                decoders[schema.name] = factory.decoder_for(channel.message_encoding, schema)
            decoded = decoders[schema.name](message.data)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is a malformed bag
            raise BagError(f"{path}: cannot decode a {schema.name} message on {channel.topic}: "
                           f"{exc}") from None
        yield channel.topic, schema.name, message.log_time, decoded


def bag_summary(path: str | Path) -> dict:
    """topic -> (type name, message count), from the bag's index."""
    out: dict = {}
    for file in bag_files(path):
        try:
            with open(file, "rb") as f:
                summary = make_reader(f).get_summary()
        except (McapError, EOFError, ValueError, OSError) as exc:
            raise BagError(f"{file}: cannot read ({exc}); " + REPAIR_HINT.format(path=path)) from None
        if summary is None:
            raise BagError(f"{file}: no summary section; " + REPAIR_HINT.format(path=path))
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            name, n = out.get(channel.topic, (schema.name if schema else "", 0))
            out[channel.topic] = (name, n + counts.get(cid, 0))
    return out
