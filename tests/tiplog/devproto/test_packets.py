"""Packet layouts: round trips, sizes of the spec's table, invalid bodies named."""

from __future__ import annotations

import math

import pytest

from tiplog.devproto.framing import FrameError
from tiplog.devproto.packets import (
    HEADER,
    HelloPacket,
    PacketType,
    TofPacket,
    Vec3Packet,
    decode_body,
    encode_packet,
)


@pytest.mark.parametrize("ptype", [PacketType.GYRO, PacketType.ACCEL, PacketType.MAG])
def test_vec3_round_trip(ptype):
    pkt = Vec3Packet(ptype, 65535, 2**40 + 3, 0.25, -9.75, 1e-3)
    body = encode_packet(pkt)
    assert len(body) == 24
    out = decode_body(body)
    assert (out.type, out.seq, out.device_us) == (ptype, 65535, 2**40 + 3)
    assert (out.x, out.y) == (0.25, -9.75) and math.isclose(out.z, 1e-3, rel_tol=1e-6)


def test_tof_round_trip():
    pkt = TofPacket(9, 123, 118.5, 2, 120.0, True)
    body = encode_packet(pkt)
    assert len(body) == 22
    out = decode_body(body)
    assert (out.range_raw_mm, out.status, out.range_smoothed_mm, out.smoothed_valid) == (118.5, 2, 120.0, True)


def test_hello_round_trip():
    pkt = HelloPacket(1, 5, "clip 1.2.0 ✓", "A1B2", {"gyro": 200.0, "accel": 240.0, "tof": 100.0, "mag": 0.0}, 0x07, 12)
    out = decode_body(encode_packet(pkt))
    assert (out.firmware, out.device_id, out.flags, out.tx_dropped) == ("clip 1.2.0 ✓", "A1B2", 7, 12)
    assert out.rates_hz == {"gyro": 200.0, "accel": 240.0, "tof": 100.0, "mag": 0.0}


def test_text_too_long_is_refused():
    with pytest.raises(ValueError, match="firmware"):
        encode_packet(HelloPacket(0, 0, "x" * 65, "id"))


def test_seq_out_of_range_is_refused():
    with pytest.raises(ValueError, match="seq"):
        encode_packet(Vec3Packet(PacketType.GYRO, 65536, 0, 0, 0, 0))


@pytest.mark.parametrize(
    ("body", "kind"),
    [
        (HEADER.pack(2, 0x10, 0, 0) + bytes(12), "version"),
        (HEADER.pack(1, 0x7E, 0, 0) + bytes(12), "unknown_type"),
        (HEADER.pack(1, 0x10, 0, 0) + bytes(11), "bad_payload"),
        (HEADER.pack(1, 0x12, 0, 0) + bytes(9) + b"\x02", "bad_payload"),  # smoothed_valid 2
        (HEADER.pack(1, 0x01, 0, 0) + bytes(24) + b"\x05ab", "bad_payload"),  # text past the end
        (HEADER.pack(1, 0x01, 0, 0) + bytes(24) + b"\x00\x00\x00", "bad_payload"),  # trailing byte
        (b"\x01\x10\x00", "truncated"),
    ],
)
def test_invalid_bodies_name_their_fault(body, kind):
    with pytest.raises(FrameError) as e:
        decode_body(body)
    assert e.value.kind == kind
