"""Damaged bags: find every intact chunk (`scan_chunks`) and rebuild a bag from them (`repair_bag`).

A recording killed hard ends in a truncated chunk and has no summary or metadata.yaml; a flipped
byte on disk breaks one chunk's CRC or compression, or a record's length. `scan_chunks` walks the
MCAP records from the start; where a record's header makes no sense it searches forward for the
next well-formed Chunk record, so one damaged chunk does not hide the ones after it. Each chunk is
decompressed and checked against its CRC.

`repair_bag` copies the schemas, channels and messages of every intact chunk into a new, properly
closed bag **beside** the old one, reads it back to verify it, and only then swaps: the damaged
file is kept as `<file>.damaged`, the old metadata.yaml (if any) as `metadata.yaml.damaged`. If
anything fails before the swap, the original bag is left exactly as it was.
"""

from __future__ import annotations

import shutil
import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import breakup_chunk

from .reader import BagError
from .writer import BagWriter

MAGIC = b"\x89MCAP0\r\n"
_CHUNK, _DATA_END, _FOOTER = 0x06, 0x0F, 0x02
_SCHEMA, _CHANNEL, _MESSAGE = 0x03, 0x04, 0x05
_KNOWN_OPCODES = set(range(0x01, 0x10))
_COMPRESSIONS = ("zstd", "lz4", "")


@dataclass
class ChunkScan:
    """One chunk of an MCAP file: where it starts (byte offset), its records if intact, else why not."""

    offset: int
    records: list = field(default_factory=list)
    error: str = ""


@dataclass
class ScanReport:
    chunks: list  # ChunkScan, in file order
    loose: list  # schema/channel/message records outside chunks
    skipped: list  # (offset, what) of byte ranges that were not records

    @property
    def bad_chunks(self) -> list:
        return [c for c in self.chunks if c.error]

    def describe(self) -> str:
        bad = self.bad_chunks
        parts = [f"chunk at byte {c.offset}: {c.error}" for c in bad[:3]]
        if len(bad) > 3:
            parts.append(f"{len(bad) - 3} more damaged chunk(s)")
        parts += [f"byte {o}: {what}" for o, what in self.skipped[:3]]
        return "; ".join(parts) or "none found"


def _chunk_at(data: bytes, pos: int) -> tuple | None:
    """(record length, Chunk) if a well-formed Chunk record starts at `pos`, else None."""
    if pos + 9 > len(data) or data[pos] != _CHUNK:
        return None
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    start = pos + 9
    if length < 8 + 8 + 8 + 4 + 4 + 8 or start + length > len(data):
        return None
    try:
        (comp_len,) = struct.unpack_from("<I", data, start + 28)
        if comp_len > 8:
            return None
        comp = data[start + 32: start + 32 + comp_len].decode("ascii")
        (rec_len,) = struct.unpack_from("<Q", data, start + 32 + comp_len)
    except (struct.error, UnicodeDecodeError):
        return None
    if comp not in _COMPRESSIONS or 32 + comp_len + 8 + rec_len != length:
        return None
    return length, Chunk.read(ReadDataStream(BytesIO(data[start: start + length])))


def _loose_record(opcode: int, content: bytes):
    stream = ReadDataStream(BytesIO(content))
    return {_SCHEMA: Schema, _CHANNEL: Channel, _MESSAGE: Message}[opcode].read(stream)


def scan_chunks(file: Path) -> ScanReport:
    """Every chunk of `file`, intact (records, CRC checked) or damaged (with the reason)."""
    data = Path(file).read_bytes()
    if not data.startswith(MAGIC):
        raise BagError(f"{file}: not an MCAP file (bad magic bytes)")
    report = ScanReport([], [], [])
    pos = len(MAGIC)
    while pos < len(data):
        found = _chunk_at(data, pos)
        if found is not None:
            length, chunk = found
            scan = ChunkScan(pos)
            try:
                scan.records = breakup_chunk(chunk, validate_crc=True)
            except Exception as exc:  # noqa: BLE001 - CRC, zstd, lz4 or record errors: this chunk is lost
                scan.error = f"{type(exc).__name__}: {exc}".strip()
            report.chunks.append(scan)
            pos += 9 + length
            continue
        if pos + 9 <= len(data) and data[pos] in _KNOWN_OPCODES:
            opcode = data[pos]
            (length,) = struct.unpack_from("<Q", data, pos + 1)
            if opcode in (_DATA_END, _FOOTER):
                break  # the summary section follows: everything it indexes was scanned already
            if opcode != _CHUNK and pos + 9 + length <= len(data):
                if opcode in (_SCHEMA, _CHANNEL, _MESSAGE):
                    try:
                        report.loose.append(_loose_record(opcode, data[pos + 9: pos + 9 + length]))
                    except Exception as exc:  # noqa: BLE001
                        report.skipped.append((pos, f"unreadable record ({exc})"))
                pos += 9 + length
                continue
        # not a record we can trust: search forward for the next well-formed chunk
        nxt = pos + 1
        while nxt < len(data) and _chunk_at(data, nxt) is None:
            nxt = data.find(bytes([_CHUNK]), nxt + 1)
            if nxt == -1:
                nxt = len(data)
        what = "truncated record at the end of the file" if nxt == len(data) else "unreadable bytes"
        report.skipped.append((pos, f"{what} ({nxt - pos} bytes skipped)"))
        pos = nxt
    return report


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
            writer.write_cdr(channel.topic, schema.name, m.data, m.log_time, m.publish_time)
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
