"""Reading what can be read of an MCAP file cut short (a crash, a full disk, a copy
interrupted): every record in file order up to the first one that is cut off or fails its
CRC, and how far that got. The recorder's `tiplog record recover` rewrites those records into
a valid indexed file; `tiplog info` and `tiplog replay` use them directly.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

MAGIC = b"\x89MCAP0\r\n"
FOOTER = struct.Struct("<BQQQI")  # opcode, record length, summary_start, summary_offset_start, summary_crc
FOOTER_OPCODE = 0x02
DATA_END = struct.Struct("<BQI")  # opcode, record length, data_section_crc
DATA_END_OPCODE = 0x0F


class _Counting:
    """Read-only stream that knows how many bytes the reader has consumed."""

    def __init__(self, f: IO[bytes]):
        self._f = f
        self.pos = 0

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        self.pos += len(data)
        return data


@dataclass
class Salvage:
    """Progress of one pass over a file: `good_bytes` is the prefix read completely;
    `complete` once the data section ended in order (nothing lost); `error` names what
    stopped the pass early."""

    source_bytes: int = 0
    good_bytes: int = 0
    complete: bool = False
    error: str = ""

    @property
    def lost_bytes(self) -> int:
        return self.source_bytes - self.good_bytes


def intact_records(f: IO[bytes], state: Salvage) -> Iterator[Any]:
    """Records of the stream `f` (chunks broken up, their CRCs checked) until the end of the
    data section or the first damaged record; `state` is updated as the pass goes."""
    counting = _Counting(f)
    reader = StreamReader(counting, emit_chunks=True, record_size_limit=1 << 31)  # type: ignore[arg-type]
    try:
        for rec in reader.records:
            if isinstance(rec, Chunk):
                yield from breakup_chunk(rec, validate_crc=True)  # raises on a damaged chunk
            elif isinstance(rec, (DataEnd, Footer)):
                state.complete = True
                state.good_bytes = state.source_bytes or counting.pos
                return
            else:
                yield rec
            state.good_bytes = counting.pos
    except (McapError, EOFError, ValueError, OSError, RuntimeError) as e:
        state.error = f"{type(e).__name__}: {e}"
    except Exception as e:  # decompression libraries raise their own types on garbage
        state.error = f"{type(e).__name__}: {e}"


def intact_messages(f: IO[bytes], state: Salvage) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """(schema, channel, message) in file order from `intact_records`."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for rec in intact_records(f, state):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message) and rec.channel_id in channels:
            ch = channels[rec.channel_id]
            yield schemas.get(ch.schema_id), ch, rec


def ends_in_order(path: str | Path) -> bool:
    """True when the file ends with the MCAP magic (its footer was written): a cheap test
    that tells a finished file from one cut short, without reading it."""
    p = Path(path)
    size = p.stat().st_size
    if size < 2 * len(MAGIC):
        return False
    with open(p, "rb") as f:
        f.seek(size - len(MAGIC))
        return f.read(len(MAGIC)) == MAGIC


def scan(path: str | Path) -> tuple[Salvage, int]:
    """One pass over the file: (how far it could be read, messages in that part)."""
    p = Path(path)
    state = Salvage(source_bytes=p.stat().st_size)
    with open(p, "rb") as f:
        n = sum(1 for _ in intact_messages(f, state))
    return state, n


def mcap_end(path: str | Path) -> int | None:
    """The byte after the closing magic of the file's MCAP data, found by reading its records in
    file order (chunks not decompressed); None when the footer or the magic is not reached (the
    end cut off, or damage before it)."""
    with open(path, "rb") as f:
        counting = _Counting(f)
        try:
            for _ in StreamReader(counting, emit_chunks=True, record_size_limit=1 << 31).records:  # type: ignore[arg-type]
                pass
        except Exception:  # noqa: BLE001 - any failure: no whole MCAP end to find
            return None
    return counting.pos


def trailer_problem(path: str | Path) -> str:
    """What is wrong with the end of the file, in a few words, or "" when it ends with a footer
    and the magic and the summary section matches the footer's CRC (when the writer set one).
    Reads only the footer and the summary, which the indexed readers trust for every offset;
    a file that does not end with the magic is read through to say how many bytes follow its
    MCAP end, if it has one."""
    p = Path(path)
    size = p.stat().st_size
    if not ends_in_order(p):
        end = mcap_end(p)
        if end is not None and end < size:
            return f"{size - end} bytes after the end of its MCAP data (byte {end}) are not MCAP (appended to it)"
        return "no MCAP footer at the end of the file (its end cut off)"
    footer_at = size - len(MAGIC) - FOOTER.size
    if footer_at < len(MAGIC):
        return "no footer record before the closing magic"
    with open(p, "rb") as f:
        f.seek(footer_at)
        opcode, length, start, offset_start, crc = FOOTER.unpack(f.read(FOOTER.size))
        if opcode != FOOTER_OPCODE or length != FOOTER.size - 9:
            return "no footer record before the closing magic"
        if start > footer_at or offset_start > footer_at or 0 < start < len(MAGIC):
            return "its footer points outside the file"
        if crc == 0:
            return ""
        begin = start or footer_at  # the CRC runs from the summary through the footer's offsets
        h = _crc32(f, begin, size - len(MAGIC) - 4 - begin)
    return "" if h == crc else "its summary (the index after the data) fails its CRC check"


def _crc32(f: IO[bytes], begin: int, length: int) -> int | None:
    """CRC-32 of `length` bytes of `f` from `begin`, or None when the file ends before them."""
    f.seek(begin)
    left, h = length, 0
    while left > 0:
        block = f.read(min(left, 1 << 22))
        if not block:
            return None
        h = zlib.crc32(block, h)
        left -= len(block)
    return h


def data_crc_fails(path: str | Path) -> bool:
    """True when the writer recorded a CRC of the data section (everything before its Data End
    record, the magic included) and the bytes there no longer match it. False when no CRC was
    recorded (zero: older files, other writers) or the Data End record is not where the footer
    puts it (`trailer_problem` speaks for such a file). Reads the whole data section once."""
    p = Path(path)
    size = p.stat().st_size
    footer_at = size - len(MAGIC) - FOOTER.size
    if footer_at < len(MAGIC):
        return False
    with open(p, "rb") as f:
        f.seek(footer_at)
        _, _, start, _, _ = FOOTER.unpack(f.read(FOOTER.size))
        end_at = (start or footer_at) - DATA_END.size
        if not len(MAGIC) <= end_at <= footer_at - DATA_END.size:
            return False
        f.seek(end_at)
        opcode, length, crc = DATA_END.unpack(f.read(DATA_END.size))
        if opcode != DATA_END_OPCODE or length != 4 or crc == 0:
            return False
        return _crc32(f, 0, end_at) != crc
