"""COBS framing with a CRC-32 trailer: the byte layer of the device protocol.

On the wire every frame is `0x00 COBS(body || crc32_le(body)) 0x00` (see
`proto/device_protocol.md`). The leading delimiter is what lets the host resynchronise at
the very next frame after garbage or a frame whose tail was lost: whatever precedes it is
cut off as its own (faulty) chunk.

CRC: CRC-32/ISO-HDLC (the zlib/Ethernet CRC): polynomial 0x04C11DB7 (reflected 0xEDB88320),
init 0xFFFFFFFF, input and output reflected, xorout 0xFFFFFFFF; check("123456789") =
0xCBF43926. Sent little-endian after the body.
"""

from __future__ import annotations

import struct
from binascii import crc32
from collections.abc import Iterator

DELIMITER = 0x00
CRC_SIZE = 4
# Longest body (packet without CRC) a device may send; the hello packet is the longest.
MAX_BODY_SIZE = 250
MAX_DECODED_SIZE = MAX_BODY_SIZE + CRC_SIZE  # 254: one COBS block, never a 0xFF code
# COBS adds one byte per started 254-byte block.
MAX_ENCODED_SIZE = MAX_DECODED_SIZE + 1 + MAX_DECODED_SIZE // 254

_CRC = struct.Struct("<I")


class FrameError(ValueError):
    """A chunk between delimiters is not a valid frame; `kind` names the fault counter."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


def crc32_le(data: bytes) -> bytes:
    """CRC-32/ISO-HDLC of `data`, 4 bytes little-endian."""
    return _CRC.pack(crc32(data))


def cobs_encode(data: bytes) -> bytes:
    """Consistent-overhead byte stuffing: the result holds no 0x00 byte."""
    return b"".join(_blocks(data))


def _blocks(data: bytes) -> Iterator[bytes]:
    # Each block: code byte (1 + number of following non-zero bytes), the bytes; a zero in
    # the input ends a block; a block of 254 non-zero bytes gets code 0xFF and no zero.
    start = 0
    n = len(data)
    while True:
        end = data.find(b"\x00", start, start + 254)
        if end == -1:
            end = min(start + 254, n)
            run = data[start:end]
            if len(run) == 254 and end < n:
                yield bytes([0xFF]) + run
                start = end
                continue
            if len(run) == 254 and end == n:
                # A full block at the very end: COBS needs no trailing empty block.
                yield bytes([0xFF]) + run
                return
            yield bytes([len(run) + 1]) + run
            return
        yield bytes([end - start + 1]) + data[start:end]
        start = end + 1


def cobs_decode(chunk: bytes) -> bytes:
    """Inverse of `cobs_encode`; FrameError('truncated'|'cobs') on a malformed chunk."""
    n = len(chunk)
    if n == 0:
        raise FrameError("cobs", "empty chunk")
    # Fast path: with no 0xFF code (every frame under 254 bytes), the decoded frame is the
    # chunk with each code byte after the first replaced by 0x00, minus the first byte.
    pos = chunk[0]
    if pos == 0xFF:
        return _cobs_decode_slow(chunk)
    if pos == n:
        return chunk[1:]
    buf = bytearray(chunk)
    while pos < n:
        code = buf[pos]
        if code == 0xFF or code == 0:
            return _cobs_decode_slow(chunk)
        buf[pos] = 0
        pos += code
    if pos != n:
        raise FrameError("truncated", f"last block runs {pos - n} byte(s) past the end (truncated?)")
    del buf[0]
    return bytes(buf)


def _cobs_decode_slow(chunk: bytes) -> bytes:
    out = bytearray()
    pos = 0
    n = len(chunk)
    while pos < n:
        code = chunk[pos]
        if code == 0:
            raise FrameError("cobs", f"zero code byte at {pos}")
        end = pos + code
        if end > n:
            raise FrameError("truncated", f"last block runs {end - n} byte(s) past the end (truncated?)")
        out += chunk[pos + 1 : end]
        pos = end
        if code != 0xFF and pos < n:
            out.append(0)
    return bytes(out)


def encode_frame(body: bytes) -> bytes:
    """`0x00 COBS(body || crc) 0x00`, ready to write to the port."""
    if len(body) > MAX_BODY_SIZE:
        raise ValueError(f"body is {len(body)} bytes; the protocol allows at most {MAX_BODY_SIZE}")
    return b"\x00" + cobs_encode(body + crc32_le(body)) + b"\x00"


def decode_chunk(chunk: bytes) -> bytes:
    """Body of one chunk found between delimiters, CRC checked; FrameError otherwise."""
    if len(chunk) > MAX_ENCODED_SIZE:
        raise FrameError("oversize", f"{len(chunk)} bytes between delimiters (max {MAX_ENCODED_SIZE})")
    dec = cobs_decode(chunk)
    if len(dec) <= CRC_SIZE:
        raise FrameError("truncated", f"{len(dec)} decoded bytes, shorter than a CRC")
    body = dec[:-CRC_SIZE]
    if crc32(body) != _CRC.unpack_from(dec, len(body))[0]:
        raise FrameError("crc", "CRC mismatch")
    return body
