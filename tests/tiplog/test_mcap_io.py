from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.reader import make_reader

from tiplog.mcap_io import (
    McapWriter,
    raw_messages,
    read_attachments,
    read_messages,
    read_metadata,
    read_summary,
    reading,
)
from tiplog.userio import UserError
from tiplog.v1 import device_pb2


def _gyro(seq: int) -> device_pb2.Gyro:
    m = device_pb2.Gyro()
    m.header.seq = seq
    m.header.stamp_ns = 1000 * seq
    m.rate_radps.z = 0.01 * seq
    return m


def test_round_trip_with_schemas_metadata_attachments(tmp_path):
    path = tmp_path / "s.mcap"
    with McapWriter(path) as w:
        for k in range(100):
            w.write("device/gyro", _gyro(k), log_time_ns=1000 * k, sequence=k)
        w.add_metadata("session", {"scenario": "static", "seed": 3})
        w.add_attachment("calibration.yaml", b"k: 1\n", "application/yaml")
    recs = list(read_messages(path))
    assert [r.message.header.seq for r in recs] == list(range(100))
    assert recs[5].message.rate_radps.z == pytest.approx(0.05)
    assert recs[7].sequence == 7 and recs[7].log_time_ns == 7000
    assert isinstance(recs[0].message, device_pb2.Gyro)
    assert read_metadata(path)["session"] == {"scenario": "static", "seed": "3"}
    assert read_attachments(path) == {"calibration.yaml": b"k: 1\n"}
    summary = read_summary(path)
    assert summary.statistics.message_count == 100
    schema = next(iter(summary.schemas.values()))
    assert schema.name == "tiplog.v1.Gyro" and schema.encoding == "protobuf"


def test_type_change_on_a_topic_is_an_error():
    w = McapWriter(io.BytesIO())
    w.write("device/gyro", _gyro(0), 0)
    with pytest.raises(ValueError, match="device/gyro.*tiplog.v1.Gyro.*tiplog.v1.Accel"):
        w.write("device/gyro", device_pb2.Accel(), 1)


def test_raw_write_and_unknown_compression():
    buf = io.BytesIO()
    with McapWriter(buf, compression="lz4") as w:
        w.write_raw("x/y", "tiplog.v1.Gyro", _gyro(9).SerializeToString(), 5)
    buf.seek(0)
    ((schema, channel, message),) = list(make_reader(buf).iter_messages())
    assert channel.topic == "x/y" and schema.name == "tiplog.v1.Gyro"
    with pytest.raises(ValueError, match="compression"):
        McapWriter(io.BytesIO(), compression="gzip")


def _chunked(path, compression="zstd"):
    with McapWriter(path, compression=compression, chunk_size=2048) as w:
        for k in range(300):
            w.write("device/gyro", _gyro(k), log_time_ns=1000 * k, sequence=k)
        w.add_metadata("session", {"scenario": "static"})
    return path


def _flip_a_chunk(src, dst):
    """`src` with 64 bytes inverted in the middle of its middle chunk; returns that chunk's offset."""
    data = bytearray(src.read_bytes())
    chunks = read_summary(src).chunk_indexes
    c = chunks[len(chunks) // 2]
    mid = c.chunk_start_offset + c.chunk_length // 2
    data[mid : mid + 64] = bytes(b ^ 0xFF for b in data[mid : mid + 64])
    dst.write_bytes(bytes(data))
    return c.chunk_start_offset


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_a_damaged_chunk_is_one_user_error_saying_where_never_wrong_messages(tmp_path, compression):
    good = _chunked(tmp_path / "good.mcap", compression)
    bad = tmp_path / "bad.mcap"
    at = _flip_a_chunk(good, bad)
    before = bad.read_bytes()
    for read in (lambda: list(read_messages(bad)), lambda: list(raw_messages(bad, ["device/gyro"]))):
        with pytest.raises(UserError) as e:
            read()
        msg = str(e.value)
        assert msg.startswith(f"{bad}: damaged at byte {at} of {len(before)}"), msg
        assert "CRC" in msg and f"tiplog record recover {bad}" in msg and "\n" not in msg
    assert bad.read_bytes() == before
    assert len(list(read_messages(good))) == 300  # an intact file reads as before


def test_a_message_that_does_not_decode_is_one_user_error(tmp_path):
    path = tmp_path / "odd.mcap"
    with McapWriter(path) as w:  # chunk CRCs fine; the payload is not a Gyro
        w.write_raw("device/gyro", "tiplog.v1.Gyro", b"\xff\xff\xff\xff", 5)
    with pytest.raises(UserError, match=r"device/gyro message \(log time 5 ns\) does not decode as tiplog.v1.Gyro"):
        list(read_messages(path))


def test_reading_passes_on_what_the_file_does_not_explain(tmp_path):
    good = _chunked(tmp_path / "good.mcap")
    with pytest.raises(ZeroDivisionError), reading(good):
        1 / 0  # noqa: B018 - a bug, not a damaged file: stays a bug


def _shuffled(path, compression, rng):
    """Two topics over small chunks whose log-time ranges overlap, with equal log times within
    and across chunks and topics (the recorder logs by arrival, so a file's order is nearly,
    not exactly, log-time order)."""
    with McapWriter(path, compression=compression, chunk_size=1024) as w:
        for k in range(600):
            t = int(rng.integers(0, 200)) * 1000 + (k // 100) * 50_000
            topic = "device/gyro" if k % 3 else "device/accel"
            w.write_raw(topic, "tiplog.v1.Gyro", _gyro(k).SerializeToString(), t, sequence=k)
    return path


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_log_time_order_is_the_librarys_to_the_last_tie(tmp_path, compression):
    path = _shuffled(tmp_path / "s.mcap", compression, np.random.default_rng(7))
    chunks = read_summary(path).chunk_indexes
    assert len(chunks) > 5 and any(
        a.message_end_time > b.message_start_time for a, b in zip(chunks, chunks[1:], strict=False)
    )  # the case the order is for: chunks that overlap in time

    def key(schema, channel, message):
        return channel.topic, message.log_time, message.publish_time, message.sequence, message.data, schema.name

    every = [m.log_time for _s, _c, m in raw_messages(path)]
    assert every == sorted(every) and len(set(every)) < len(every)  # with ties to order
    for topics_ in (None, ["device/gyro"], ["device/accel"], ["device/none"]):
        with open(path, "rb") as f:
            want = [key(*m) for m in make_reader(f).iter_messages(topics=topics_, log_time_order=True)]
        got = [key(*m) for m in raw_messages(path, topics_)]
        assert got == want
        assert [(r.topic, r.log_time_ns, r.sequence) for r in read_messages(path, topics_)] == [
            k[:2] + k[3:4] for k in want
        ]


def test_a_file_without_chunks_reads_in_log_time_order_too(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "flat.mcap"
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        sid = w.register_schema("tiplog.v1.Gyro", "protobuf", b"")
        cid = w.register_channel("device/gyro", "protobuf", sid)
        for k, t in enumerate([30, 10, 20, 10]):
            w.add_message(cid, log_time=t, data=_gyro(k).SerializeToString(), publish_time=t, sequence=k)
        w.finish()
    assert [(m.log_time, m.sequence) for _s, _c, m in raw_messages(path)] == [(10, 1), (10, 3), (20, 2), (30, 0)]


class _Pipe(io.RawIOBase):
    """A stream that cannot seek (a pipe): the library reads it from start to end."""

    def __init__(self, data: bytes):
        self._b = io.BytesIO(data)

    def readable(self):
        return True

    def seekable(self):
        return False

    def readinto(self, buf):
        return self._b.readinto(buf)


def test_a_stream_that_cannot_seek_reads_too(tmp_path):
    path = _chunked(tmp_path / "s.mcap")
    recs = list(read_messages(io.BufferedReader(_Pipe(path.read_bytes()))))
    assert [r.message.header.seq for r in recs] == list(range(300))


_WRITE_MAPS = """
import sys
from tiplog.mcap_io import McapWriter
from tiplog.v1 import fusion_pb2
d = fusion_pb2.FusionDiagnostics(mode="full")
for k in ("tof", "rcm", "gravity", "vision_tip", "depth_anchor", "rest", "tof_mapped", "vision_axis"):
    d.updates[k] = len(k)
    d.innovation_nis[k] = 0.5 * len(k)
with McapWriter(sys.argv[1]) as w:
    w.write("fusion/diagnostics", d, 1)
"""


def test_the_same_messages_make_the_same_file_in_every_process(tmp_path):
    """protobuf orders a map's entries by a hash seeded per process; the files of two runs of
    `tiplog fusion run` on one input must still be equal byte for byte."""
    import subprocess
    import sys

    paths = [tmp_path / f"{k}.mcap" for k in range(3)]
    for p in paths:
        subprocess.run([sys.executable, "-c", _WRITE_MAPS, str(p)], check=True)
    first = paths[0].read_bytes()
    assert all(p.read_bytes() == first for p in paths[1:])
    (rec,) = read_messages(paths[0])
    assert dict(rec.message.updates) == {k: len(k) for k in rec.message.updates} and len(rec.message.updates) == 8
