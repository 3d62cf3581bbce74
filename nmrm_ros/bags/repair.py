"""Damaged bags: rebuild a bag from every intact chunk (`repair_bag`; the chunks are found by
`chunks.scan_chunks`).

A recording killed hard ends in a truncated chunk and has no summary or metadata.yaml; a flipped
byte on disk breaks one chunk's CRC or compression, or a record's length.

`repair_bag` copies the schemas, channels and messages of every intact chunk into a new, properly
closed bag **beside** the old one, reads it back to verify it, and only then swaps: the damaged
file is kept as `<file>.damaged`, the old metadata.yaml (if any) as `metadata.yaml.damaged`. If
anything fails before the swap, the original bag is left exactly as it was.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Schema

from .chunks import scan_chunks
from .errors import BagError
from .writer import BagWriter


@dataclass
class RepairReport:
    path: Path
    messages: int
    topics: dict
    damaged: str  # what was found damaged ("none found" if the file was intact)
    backup: Path | None
    chunks_kept: int = 0
    chunks_lost: int = 0
    messages_without_channel: int = 0


def repair_bag(path: str | Path) -> RepairReport:
    """Rebuild the bag at `path` (a directory, or a bare .mcap) from its intact chunks."""
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
    scan = scan_chunks(file)
    schemas: dict = {}
    channels: dict = {}
    messages: list = []
    for record in scan.loose + [r for c in scan.chunks if not c.error for r in c.records]:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            messages.append(record)
    if not messages:
        raise BagError(f"{file}: no readable message ({scan.describe()}); the bag is left as it was")

    work = directory.with_name(directory.name + ".repairing")
    shutil.rmtree(work, ignore_errors=True)
    try:
        writer = BagWriter(work, file_name=file.name)
        messages.sort(key=lambda m: (m.log_time, m.sequence))
        orphans = 0
        for m in messages:
            channel = channels.get(m.channel_id)
            schema = schemas.get(channel.schema_id) if channel else None
            if channel is None or schema is None:
                orphans += 1
                continue
            # the bag's own schema: its messages may be of an older definition than today's
            writer.write_cdr(channel.topic, schema.name, m.data, m.log_time, m.publish_time, schema.data)
        counts = dict(writer.counts)
        writer.close()
        _verify(work, sum(counts.values()))
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    # the new bag is complete and verified: swap, keeping the damaged originals
    backup = file.with_name(file.name + ".damaged")
    file.replace(backup)
    meta = directory / "metadata.yaml"
    if meta.exists():
        meta.replace(directory / "metadata.yaml.damaged")
    (work / file.name).replace(file)
    (work / "metadata.yaml").replace(meta)
    shutil.rmtree(work, ignore_errors=True)
    lost = len(scan.bad_chunks)
    return RepairReport(directory, sum(counts.values()), counts, scan.describe(), backup,
                        chunks_kept=len(scan.chunks) - lost, chunks_lost=lost, messages_without_channel=orphans)


def _verify(bag: Path, expected: int) -> None:
    from .reader import iter_raw

    n = sum(1 for _ in iter_raw(bag))
    if n != expected:
        raise BagError(f"{bag}: the rebuilt bag holds {n} messages, expected {expected}; nothing was changed")
