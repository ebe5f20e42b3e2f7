"""COBS and CRC-32 framing: the spec's test vectors, round trips, malformed chunks."""

from __future__ import annotations

import binascii
import random

import pytest

from tiplog.devproto.framing import (
    MAX_BODY_SIZE,
    MAX_ENCODED_SIZE,
    FrameError,
    cobs_decode,
    cobs_encode,
    crc32_le,
    decode_chunk,
    encode_frame,
)
from tiplog.devproto.packets import PacketType, Vec3Packet, encode_packet, encode_packet_frame


def test_crc_check_value_of_the_spec():
    assert binascii.crc32(b"123456789") == 0xCBF43926
    assert crc32_le(b"123456789") == bytes.fromhex("2639f4cb")


@pytest.mark.parametrize(
    ("data", "encoded"),
    [
        ("", "01"),
        ("00", "0101"),
        ("0000", "010101"),
        ("11220033", "0311220233"),
        ("11223344", "0511223344"),
        ("11000000", "02110101 01".replace(" ", "")),
    ],
)
def test_cobs_vectors(data, encoded):
    assert cobs_encode(bytes.fromhex(data)).hex() == encoded
    assert cobs_decode(bytes.fromhex(encoded)).hex() == data


def test_cobs_254_and_255_nonzero_bytes_use_a_ff_code():
    d254 = bytes(range(1, 255))
    assert cobs_encode(d254) == b"\xff" + d254
    d255 = d254 + b"\x01"
    assert cobs_encode(d255) == b"\xff" + d254 + b"\x02\x01"
    assert cobs_decode(cobs_encode(d255)) == d255


def test_cobs_round_trip_random():
    rng = random.Random(5)
    for n in range(0, 700, 7):
        data = bytes(rng.choice((0, 0, 1, 255, rng.randrange(256))) for _ in range(n))
        enc = cobs_encode(data)
        assert 0 not in enc
        assert cobs_decode(enc) == data


def test_worked_example_of_the_spec():
    pkt = Vec3Packet(PacketType.GYRO, 258, 1_000_000, 0.5, -1.0, 2.0)
    body = encode_packet(pkt)
    assert body.hex() == "0110020140420f00000000000000003f000080bf00000040"
    assert crc32_le(body).hex() == "7c485463"
    wire = "00080110020140420f01010101010101023f010380bf010106407c48546300"
    assert encode_packet_frame(pkt).hex() == wire


def test_frame_has_both_delimiters_and_decodes():
    body = bytes(range(40))
    frame = encode_frame(body)
    assert frame[0] == 0 and frame[-1] == 0 and 0 not in frame[1:-1]
    assert decode_chunk(frame[1:-1]) == body


def test_longest_body_fits_the_encoded_limit():
    frame = encode_frame(bytes(MAX_BODY_SIZE))
    assert len(frame) - 2 <= MAX_ENCODED_SIZE
    with pytest.raises(ValueError, match="at most 250"):
        encode_frame(bytes(MAX_BODY_SIZE + 1))


@pytest.mark.parametrize(
    ("chunk", "kind"),
    [
        (b"\x05\x01\x02", "truncated"),  # code runs past the end
        (b"\x02\x01", "truncated"),  # decodes to 1 byte: shorter than a CRC
        (b"\x01" * (MAX_ENCODED_SIZE + 1), "oversize"),
    ],
)
def test_malformed_chunks_name_their_fault(chunk, kind):
    with pytest.raises(FrameError) as e:
        decode_chunk(chunk)
    assert e.value.kind == kind


def test_every_single_bit_flip_is_rejected():
    frame = encode_frame(bytes(range(1, 30)))
    inner = frame[1:-1]
    for i in range(len(inner)):
        for b in range(8):
            bad = bytearray(inner)
            bad[i] ^= 1 << b
            for piece in bytes(bad).split(b"\x00"):  # a flip to 0x00 splits the frame
                if piece:
                    with pytest.raises(FrameError):
                        decode_chunk(piece)
