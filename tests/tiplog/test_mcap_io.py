from __future__ import annotations

import io

import pytest
from mcap.reader import make_reader

from tiplog.mcap_io import McapWriter, read_attachments, read_messages, read_metadata, read_summary
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
