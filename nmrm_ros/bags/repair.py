"""`nmrm bag repair`: make a bag whose recording was killed (no summary, no metadata.yaml, a
truncated last chunk) readable again.

The MCAP file is read record by record from the start; every schema, channel and message of the
complete chunks before the damage is copied into a new, properly closed MCAP, and metadata.yaml is
written. The damaged original is kept beside it as `<file>.damaged` (nothing is deleted).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from .reader import BagError
from .writer import BagWriter


@dataclass
class RepairReport:
    path: Path
    messages: int
    topics: dict
    damaged: str  # what stopped the scan ("" if the file was complete)
    backup: Path | None


def salvage(file: Path) -> tuple:
    """(schemas, channels, messages, error text) readable from the start of an MCAP file."""
    schemas: dict = {}
    channels: dict = {}
    messages: list = []
    error = ""

    def take(record) -> None:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            messages.append(record)

    with open(file, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Chunk):
                    for inner in breakup_chunk(record, validate_crc=True):
                        take(inner)
                elif isinstance(record, (DataEnd, Footer)):
                    break
                else:
                    take(record)
        except Exception as exc:  # noqa: BLE001 - the damage we are here to get past
            error = f"{type(exc).__name__}: {exc}" or type(exc).__name__
    return schemas, channels, messages, error


def repair_bag(path: str | Path) -> RepairReport:
    """Rewrite the bag at `path` (a directory, or a bare .mcap) from what can be salvaged."""
    path = Path(path)
    if path.is_file():
        directory, files = path.parent, [path]
    elif path.is_dir():
        directory, files = path, sorted(path.glob("*.mcap"))
    else:
        raise BagError(f"no bag at {path}")
    if len(files) != 1:
        raise BagError(f"{path}: expected one .mcap file to repair, found {len(files)}")
    file = files[0]
    schemas, channels, messages, error = salvage(file)
    if not schemas and not messages:
        raise BagError(f"{file}: nothing readable ({error or 'empty'})")
    backup = file.with_name(file.name + ".damaged")
    file.replace(backup)
    (directory / "metadata.yaml").unlink(missing_ok=True)
    writer = BagWriter(directory, overwrite=True, file_name=file.name)
    messages.sort(key=lambda m: (m.log_time, m.sequence))
    for m in messages:
        channel = channels.get(m.channel_id)
        schema = schemas.get(channel.schema_id) if channel else None
        if channel is None or schema is None:
            continue
        writer.write_cdr(channel.topic, schema.name, m.data, m.log_time, m.publish_time)
    counts = dict(writer.counts)
    writer.close()
    return RepairReport(directory, sum(counts.values()), counts, error, backup)
