"""Streaming parser: any chunking gives the same packets, faults are counted by kind,
sequence gaps and wraps and device resets are recognised."""

from __future__ import annotations

import itertools
import random

from tiplog.devproto.framing import encode_frame
from tiplog.devproto.packets import HEADER, PacketType, Vec3Packet, encode_packet_frame
from tiplog.devproto.parser import StreamParser
from tiplog.devproto.synthetic import synthetic_packets

RATES = {"gyro": 200.0, "accel": 240.0, "tof": 100.0, "mag": 100.0}


def _numbered(n: int, seed: int = 0):
    seqs: dict = {}
    out = []
    for pkt in itertools.islice(synthetic_packets(RATES, seed=seed), n):
        pkt.seq = seqs.get(pkt.type, 0)
        seqs[pkt.type] = (pkt.seq + 1) % 65536
        out.append(pkt)
    return out


def _key(p):
    return (p.type, p.seq, p.device_us)


def test_random_chunking_gives_the_same_packets():
    pkts = _numbered(2000)
    data = b"".join(encode_packet_frame(p) for p in pkts)
    rng = random.Random(3)
    parser = StreamParser()
    out = []
    i = 0
    while i < len(data):
        n = rng.randint(1, 300)
        out += parser.feed(data[i : i + n])
        i += n
    assert [_key(p) for p in out] == [_key(p) for p in pkts]
    assert parser.frames_ok == 2000
    assert sum(v for k, v in parser.faults.items()) == 0


def test_garbage_truncation_and_flips_lose_only_the_damaged_frames():
    pkts = _numbered(3000, seed=1)
    rng = random.Random(9)
    data = bytearray()
    good = []
    for p in pkts:
        frame = encode_packet_frame(p)
        r = rng.random()
        if r < 0.05:
            data += rng.randbytes(rng.randint(1, 80))  # garbage before an intact frame
            good.append(p)
        elif r < 0.08:
            frame = frame[: rng.randint(1, len(frame) - 2)]  # tail lost
        elif r < 0.11:
            b = bytearray(frame)
            b[rng.randint(1, len(frame) - 2)] ^= 1 << rng.randrange(8)
            frame = bytes(b)
        else:
            good.append(p)
        data += frame
    parser = StreamParser()
    out = parser.feed(bytes(data))
    assert [_key(p) for p in out] == [_key(p) for p in good]
    f = parser.faults
    assert f["crc"] > 0 and f["truncated"] + f["cobs"] > 0 and f["garbage_bytes"] > 0


def test_long_run_without_delimiter_is_dropped_and_sync_recovers():
    parser = StreamParser()
    assert parser.feed(b"\x07" * 1000) == []
    assert parser.faults["oversize"] == 1
    pkt = Vec3Packet(PacketType.GYRO, 0, 10, 1, 2, 3)
    assert [p.seq for p in parser.feed(encode_packet_frame(pkt))] == [0]


def test_sequence_gap_wrap_and_reset():
    parser = StreamParser()

    def feed(seq, us):
        return parser.feed(encode_packet_frame(Vec3Packet(PacketType.GYRO, seq, us, 0, 0, 0)))[0]

    assert feed(65534, 100).seq_ext == 65534
    assert feed(65535, 200).seq_ext == 65535
    assert feed(0, 300).seq_ext == 65536  # wrap: no gap
    assert parser.faults["seq_gaps"] == 0
    assert feed(4, 400).seq_ext == 65540  # 1, 2, 3 lost
    assert (parser.faults["seq_gaps"], parser.faults["seq_gap_samples"]) == (1, 3)
    assert feed(0, 50).seq_ext == 65541  # device clock back: reboot, seq_ext still grows
    assert parser.faults["device_resets"] == 1
    assert feed(1, 60).seq_ext == 65542
    assert parser.faults["seq_gaps"] == 1


def test_wrong_version_and_unknown_type_are_counted():
    parser = StreamParser()
    data = encode_frame(HEADER.pack(9, 0x10, 0, 0) + bytes(12)) + encode_frame(HEADER.pack(1, 0x55, 0, 0))
    assert parser.feed(data) == []
    assert parser.faults["version"] == 1 and parser.faults["unknown_type"] == 1


def test_reset_drops_a_partial_frame():
    parser = StreamParser()
    frame = encode_packet_frame(Vec3Packet(PacketType.GYRO, 0, 10, 1, 2, 3))
    parser.feed(frame[:10])
    parser.reset()
    assert parser.faults["truncated"] == 1 and parser.pending_bytes == 0
    assert len(parser.feed(frame)) == 1
