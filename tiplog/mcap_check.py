"""The records of an MCAP file that carry no CRC of their own, checked against the summary
(the index after the data), which does.

Chunks are checked by their CRC as they are decompressed (`tiplog.mcap_io.open_reader`) and the
summary by the footer's CRC (`tiplog.mcap_salvage.trailer_problem`), but a Metadata record, the
Message Index records after each chunk and a chunk's record header have none: a damaged
metadata record was read as whatever its bytes now say (the calibration a fusion run uses, or
a traceback), and damaged message indexes went unnoticed. Each one's place, length and name
are in the summary; a record that does not match them, or does not parse to exactly its
length, is damaged.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import IO, Any

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Metadata

_PREFIX = struct.Struct("<BQ")  # opcode, record length (of what follows)
_MESSAGE_INDEX_HEAD = struct.Struct("<HI")  # channel id, byte length of the (log time, offset) pairs
_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])


class DamagedRecord(ValueError):
    """A record that does not match the summary's index of it: `offset` is its first byte."""

    def __init__(self, offset: int, what: str):
        super().__init__(f"damaged at byte {offset} ({what})")
        self.offset = offset
        self.what = what


def _strings(body: bytes, pos: int, end: int) -> Iterator[tuple[str, int]]:
    """Length-prefixed UTF-8 strings of body[pos:end], each with the position after it; a
    length that runs past `end` or bytes that are not UTF-8 are a ValueError."""
    while pos < end:
        if pos + 4 > end:
            raise ValueError("a string's length runs past its map")
        (n,) = struct.unpack_from("<I", body, pos)
        if pos + 4 + n > end:
            raise ValueError("a string runs past its map")
        yield body[pos + 4 : pos + 4 + n].decode("utf-8"), pos + 4 + n
        pos += 4 + n


def _parse_metadata(raw: bytes) -> Metadata:
    """The Metadata record `raw` (opcode and length included), parsed to exactly its length."""
    opcode, length = _PREFIX.unpack_from(raw)
    if opcode != Opcode.METADATA:
        raise ValueError(f"opcode {opcode:#04x} where the index has a metadata record")
    if length != len(raw) - _PREFIX.size:
        raise ValueError(f"its length says {length} bytes, the index {len(raw) - _PREFIX.size}")
    name, pos = next(_strings(raw, _PREFIX.size, len(raw)), ("", len(raw)))
    if pos + 4 > len(raw):
        raise ValueError("it ends before its map")
    (map_len,) = struct.unpack_from("<I", raw, pos)
    if pos + 4 + map_len != len(raw):
        raise ValueError(f"its map says {map_len} bytes, the record holds {len(raw) - pos - 4}")
    items = [s for s, _ in _strings(raw, pos + 4, len(raw))]
    if len(items) % 2:
        raise ValueError("its map has a key without a value")
    return Metadata(name=name, metadata=dict(zip(items[::2], items[1::2], strict=True)))


def metadata_records(f: IO[bytes], summary: Any, size: int) -> Iterator[Metadata]:
    """Every Metadata record the summary indexes, in its order, each checked against its index
    entry (place, length, name) and parsed to exactly its length; DamagedRecord otherwise.
    `size` is the file's length in bytes."""
    for ix in summary.metadata_indexes:
        if ix.length < _PREFIX.size or ix.offset + ix.length > size:
            raise DamagedRecord(ix.offset, f"metadata record {ix.name!r}: its index points outside the file")
        f.seek(ix.offset)
        raw = f.read(ix.length)
        try:
            rec = _parse_metadata(raw)
        except (ValueError, struct.error) as e:  # UnicodeDecodeError is a ValueError
            what = "its text is not UTF-8" if isinstance(e, UnicodeDecodeError) else str(e)
            raise DamagedRecord(ix.offset, f"metadata record {ix.name!r}: {what}") from None
        if rec.name != ix.name:
            raise DamagedRecord(ix.offset, f"metadata record {ix.name!r}: it is named {rec.name[:40]!r}")
        yield rec


def message_index_problem(f: IO[bytes], summary: Any, size: int) -> DamagedRecord | None:
    """The first chunk header or Message Index record that does not match the summary's chunk
    index (opcode, length, channel, entries within the chunk's times and bytes), or None.
    Reads the 9-byte chunk headers and the message indexes (16 bytes a message), no chunk data."""
    for ci in summary.chunk_indexes:
        f.seek(ci.chunk_start_offset)
        head = f.read(_PREFIX.size)
        if len(head) < _PREFIX.size or _PREFIX.unpack(head) != (Opcode.CHUNK, ci.chunk_length - _PREFIX.size):
            return DamagedRecord(ci.chunk_start_offset, "a chunk's record header does not match its index")
        start = ci.chunk_start_offset + ci.chunk_length
        if start + ci.message_index_length > size:
            return DamagedRecord(start, "the message indexes of a chunk run past the end of the file")
        f.seek(start)
        block = f.read(ci.message_index_length)
        pos = 0
        for channel_id, offset in sorted(ci.message_index_offsets.items(), key=lambda kv: kv[1]):
            at = f"the message index of channel {channel_id}"
            if offset - start != pos or pos + _PREFIX.size + _MESSAGE_INDEX_HEAD.size > len(block):
                return DamagedRecord(start + pos, f"{at} is not where the chunk's index puts it")
            opcode, length = _PREFIX.unpack_from(block, pos)
            cid, n = _MESSAGE_INDEX_HEAD.unpack_from(block, pos + _PREFIX.size)
            body = pos + _PREFIX.size + _MESSAGE_INDEX_HEAD.size
            if opcode != Opcode.MESSAGE_INDEX or cid != channel_id or n % _ENTRY.itemsize:
                return DamagedRecord(offset, f"{at}: its opcode, channel or length is not a message index's")
            if length != _MESSAGE_INDEX_HEAD.size + n or body + n > len(block):
                return DamagedRecord(offset, f"{at}: its length does not match the chunk's index")
            e = np.frombuffer(block, _ENTRY, n // _ENTRY.itemsize, body)
            t_ok = (e["log_time"] >= ci.message_start_time) & (e["log_time"] <= ci.message_end_time)
            if not (t_ok.all() and (e["offset"] < ci.uncompressed_size).all()):
                return DamagedRecord(offset, f"{at}: an entry points outside its chunk's times or bytes")
            pos = body + n
        if pos != len(block):
            return DamagedRecord(start + pos, "a chunk's message indexes do not fill the length its index gives")
    return None
