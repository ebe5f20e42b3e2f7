"""Packet layouts of the device protocol (version 1): dataclasses, encode, decode.

A packet body is a 12-byte header `<B version><B type><H seq><Q device_us>` followed by a
payload fixed by the type; all little-endian, floats IEEE-754 binary32. The byte tables
live in `proto/device_protocol.md`; this module is their executable form.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

from tiplog.devproto.framing import MAX_BODY_SIZE, FrameError, encode_frame

PROTOCOL_VERSION = 1
HEADER = struct.Struct("<BBHQ")  # version, type, seq, device_us
SEQ_MODULO = 1 << 16
MAX_TEXT_BYTES = 64


class PacketType(IntEnum):
    HELLO = 0x01
    GYRO = 0x10
    ACCEL = 0x11
    TOF = 0x12
    MAG = 0x13


# Stream names used by counters, status maps and topics (device/<name>).
STREAM_NAMES: dict[PacketType, str] = {
    PacketType.HELLO: "hello",
    PacketType.GYRO: "gyro",
    PacketType.ACCEL: "accel",
    PacketType.TOF: "tof",
    PacketType.MAG: "mag",
}

_VEC3 = struct.Struct("<3f")
_TOF = struct.Struct("<fBfB")  # range_raw_mm, status, range_smoothed_mm, smoothed_valid
_HELLO_FIXED = struct.Struct("<BBHI4f")  # flags, reserved, reserved, tx_dropped, 4 rates

# Hello flags.
FLAG_IMU_OK = 0x01
FLAG_TOF_OK = 0x02
FLAG_TX_OVERFLOW = 0x04


@dataclass(slots=True)
class Vec3Packet:
    """Gyro (rad/s), accel (m/s^2, specific force) or mag (uT) sample, IMU frame."""

    type: PacketType
    seq: int  # 16-bit per-stream counter as sent
    device_us: int  # device clock, us since boot
    x: float
    y: float
    z: float
    seq_ext: int = -1  # the host's unwrapped 64-bit counter (set by the parser)


@dataclass(slots=True)
class TofPacket:
    """VL53L0X raw range with its status, and the firmware's 5-sample moving average."""

    seq: int
    device_us: int
    range_raw_mm: float
    status: int  # tiplog.v1.TofStatus value (1 = valid)
    range_smoothed_mm: float
    smoothed_valid: bool
    seq_ext: int = -1
    type: PacketType = PacketType.TOF


@dataclass(slots=True)
class HelloPacket:
    """Handshake and device status, sent at boot and then every second."""

    seq: int
    device_us: int
    firmware: str
    device_id: str
    rates_hz: dict[str, float] = field(default_factory=dict)  # gyro, accel, tof, mag
    flags: int = FLAG_IMU_OK | FLAG_TOF_OK
    tx_dropped: int = 0  # samples the device's output queue dropped since boot
    seq_ext: int = -1
    type: PacketType = PacketType.HELLO


Packet = Vec3Packet | TofPacket | HelloPacket
_RATE_KEYS = ("gyro", "accel", "tof", "mag")


def _text(value: str, name: str) -> bytes:
    raw = value.encode()
    if len(raw) > MAX_TEXT_BYTES:
        raise ValueError(f"{name} is {len(raw)} bytes of UTF-8; at most {MAX_TEXT_BYTES}")
    return bytes([len(raw)]) + raw


def encode_packet(pkt: Packet) -> bytes:
    """Body bytes (header + payload, without CRC) of `pkt`."""
    if not 0 <= pkt.seq < SEQ_MODULO:
        raise ValueError(f"seq {pkt.seq} outside 0..65535")
    if not 0 <= pkt.device_us < 1 << 64:
        raise ValueError(f"device_us {pkt.device_us} outside the u64 range")
    head = HEADER.pack(PROTOCOL_VERSION, int(pkt.type), pkt.seq, pkt.device_us)
    if isinstance(pkt, Vec3Packet):
        return head + _VEC3.pack(pkt.x, pkt.y, pkt.z)
    if isinstance(pkt, TofPacket):
        return head + _TOF.pack(pkt.range_raw_mm, pkt.status, pkt.range_smoothed_mm, int(pkt.smoothed_valid))
    rates = [float(pkt.rates_hz.get(k, 0.0)) for k in _RATE_KEYS]
    body = head + _HELLO_FIXED.pack(pkt.flags, 0, 0, pkt.tx_dropped, *rates)
    body += _text(pkt.firmware, "firmware") + _text(pkt.device_id, "device_id")
    if len(body) > MAX_BODY_SIZE:  # cannot happen with 64-byte texts; kept for edits
        raise ValueError(f"hello body {len(body)} bytes exceeds {MAX_BODY_SIZE}")
    return body


def encode_packet_frame(pkt: Packet) -> bytes:
    """Wire bytes of `pkt`: `0x00 COBS(body || crc32) 0x00`."""
    return encode_frame(encode_packet(pkt))


_VEC3_TYPES = {int(PacketType.GYRO): PacketType.GYRO, int(PacketType.ACCEL): PacketType.ACCEL,
               int(PacketType.MAG): PacketType.MAG}  # fmt: skip
_VEC3_LEN = HEADER.size + _VEC3.size
_TOF_LEN = HEADER.size + _TOF.size


def decode_body(body: bytes) -> Packet:
    """Packet from a CRC-checked body; FrameError('version'|'unknown_type'|'bad_payload')."""
    if len(body) < HEADER.size:
        raise FrameError("truncated", f"body of {len(body)} bytes is shorter than the {HEADER.size}-byte header")
    version, ptype, seq, device_us = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError("version", f"protocol version {version}, this host speaks {PROTOCOL_VERSION}")
    vt = _VEC3_TYPES.get(ptype)
    if vt is not None:
        if len(body) != _VEC3_LEN:
            raise FrameError("bad_payload", f"{vt.name} body is {len(body)} bytes, expected {_VEC3_LEN}")
        x, y, z = _VEC3.unpack_from(body, HEADER.size)
        return Vec3Packet(vt, seq, device_us, x, y, z)
    if ptype == PacketType.TOF:
        if len(body) != _TOF_LEN:
            raise FrameError("bad_payload", f"TOF body is {len(body)} bytes, expected {_TOF_LEN}")
        raw, status, smoothed, valid = _TOF.unpack_from(body, HEADER.size)
        if valid > 1:
            raise FrameError("bad_payload", f"TOF smoothed_valid is {valid}, expected 0 or 1")
        return TofPacket(seq, device_us, raw, status, smoothed, bool(valid))
    if ptype == PacketType.HELLO:
        return _decode_hello(body, seq, device_us)
    raise FrameError("unknown_type", f"packet type 0x{ptype:02x} is not defined in version {PROTOCOL_VERSION}")


def _decode_hello(body: bytes, seq: int, device_us: int) -> HelloPacket:
    off = HEADER.size
    if len(body) < off + _HELLO_FIXED.size + 2:
        raise FrameError("bad_payload", f"HELLO body is {len(body)} bytes, too short")
    flags, _r1, _r2, dropped, *rates = _HELLO_FIXED.unpack_from(body, off)
    off += _HELLO_FIXED.size
    texts = []
    for name in ("firmware", "device_id"):
        if off >= len(body):
            raise FrameError("bad_payload", f"HELLO ends before {name}")
        n = body[off]
        if n > MAX_TEXT_BYTES or off + 1 + n > len(body):
            raise FrameError("bad_payload", f"HELLO {name} length {n} runs past the body")
        try:
            texts.append(body[off + 1 : off + 1 + n].decode())
        except UnicodeDecodeError:
            raise FrameError("bad_payload", f"HELLO {name} is not UTF-8") from None
        off += 1 + n
    if off != len(body):
        raise FrameError("bad_payload", f"HELLO has {len(body) - off} trailing byte(s)")
    return HelloPacket(seq, device_us, texts[0], texts[1], dict(zip(_RATE_KEYS, rates, strict=True)), flags, dropped)
