"""Finding the intact chunks of an MCAP file (`scan_chunks`), damaged or not: what reading a bag
reports when it is damaged, and what `repair_bag` rebuilds a bag from.

`scan_chunks` walks the MCAP records from the start; where a record's header makes no sense it
searches forward for the next well-formed Chunk record, so one damaged chunk does not hide the
ones after it. Each chunk is decompressed and checked against its CRC.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import breakup_chunk

from .errors import BagError

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
