"""The recorder on a real Zenoh session: replay -> record round trip, a full disk with the
alarm on recorder/status, automatic start on device/status, and the control commands."""

from __future__ import annotations

import base64
import collections
import os
import random
import re
import statistics
import subprocess
import sys

import pytest
from foxglove_schemas_protobuf import RawImage_pb2

from services.recorder.info import inspect
from services.recorder.replay import LATE_NS
from tests.conftest import ROOT
from tests.services.recorder.test_core import FullDisk
from tiplog.mcap_io import McapWriter, read_metadata
from tiplog.v1 import device_pb2, recorder_pb2

A = recorder_pb2.RecorderAction
S = recorder_pb2.RecorderState
T0 = 7_000_000_000


def make_session(path) -> dict[str, list[tuple[int, bytes]]]:
    """1 s of gyro 200 Hz, accel 240 Hz, ToF 100 Hz and small rgb8 frames at 15 fps."""
    streams = {"device/gyro": 200, "device/accel": 240, "device/tof": 100, "camera/image": 15}
    out: dict[str, list[tuple[int, bytes]]] = collections.defaultdict(list)
    rows = []
    for topic, hz in streams.items():
        for k in range(hz):
            t = T0 + k * 1_000_000_000 // hz + (k * 7919 % 13) * 1000  # a little irregular
            if topic == "device/gyro":
                m = device_pb2.Gyro()
                m.rate_radps.x = 0.001 * k
            elif topic == "device/accel":
                m = device_pb2.Accel()
                m.specific_force_mps2.z = 9.81 + 0.001 * k
            elif topic == "device/tof":
                m = device_pb2.Tof(range_raw_mm=100.0 + k, status=device_pb2.TOF_STATUS_VALID)
            else:
                m = RawImage_pb2.RawImage(width=32, height=24, encoding="rgb8", step=96, data=bytes([k]) * (96 * 24))
                m.timestamp.FromNanoseconds(t)
            if topic != "camera/image":
                m.header.seq = k
                m.header.stamp_ns = t
            rows.append((t, topic, m, k))
    rows.sort(key=lambda r: r[0])
    with McapWriter(path) as w:
        for t, topic, m, k in rows:
            w.write(topic, m, log_time_ns=t, sequence=k)
            out[topic].append((t, m.SerializeToString()))
    return out


def read_raw(path):
    from mcap.reader import make_reader

    got: dict[str, list] = collections.defaultdict(list)
    with open(path, "rb") as f:
        for _s, ch, msg in make_reader(f).iter_messages(log_time_order=True):
            got[ch.topic].append(msg)
    return got


@pytest.mark.realtime  # the replay within 1 ms of the recorded timing
def test_replay_then_record_is_identical_in_content_and_timing(served_recorder, bus_pair_configs, tmp_path):
    original = make_session(tmp_path / "orig.mcap")
    srv = served_recorder(camera_archive="raw")  # byte for byte: the camera too, as it came
    assert srv.command(A.RECORDER_ACTION_START, "replay test", "again").ok
    # `tiplog replay` in its own process: in this one the recorder's threads would share the GIL.
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "tiplog.cli",
            "replay",
            str(tmp_path / "orig.mcap"),
            "--wait",
            "20",
            "--connect",
            bus_pair_configs[0].listen[0],
            "--prefix",
            bus_pair_configs[0].prefix,
        ],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "replayed 555 messages" in proc.stdout, proc.stdout
    expected = {t: len(v) for t, v in original.items()}
    srv.status.wait(lambda s: all(t in s.topics and s.topics[t].written == n for t, n in expected.items()))
    reply = srv.command(A.RECORDER_ACTION_STOP)
    assert reply.ok, reply.message
    got = read_raw(reply.status.path)
    for topic, msgs in original.items():
        rec = got[topic]
        assert [m.data for m in rec] == [p for _t, p in msgs], f"{topic}: payloads differ"
        assert [m.sequence for m in rec] == list(range(len(msgs)))
    # Timing: each replayed put (publish_time) against its original log time, all topics,
    # after removing the one constant offset between the two clocks.
    diffs = [
        m.publish_time - t for topic, msgs in original.items() for m, (t, _p) in zip(got[topic], msgs, strict=True)
    ]
    offset = statistics.median(diffs)
    err_ms = sorted(abs(d - offset) / 1e6 for d in diffs)
    head = proc.stdout.splitlines()[0]
    late_ms = LATE_NS / 1e6  # what the replay counts as late
    m = re.search(rf"(\d+) late by over {late_ms:g} ms", head)
    assert m, head
    late_puts = int(m.group(1))
    over = sum(e > late_ms for e in err_ms)
    summary = f"{over} of {len(err_ms)} over {late_ms:g} ms; median {statistics.median(err_ms):.3f} ms, max {err_ms[-1]:.3f} ms ({head})"
    print("replay timing error:", summary)
    # How many puts land within 1 ms of their time is the host's: on a loaded CI machine the
    # scheduler wakes the replay late now and then (measured on a 2-core host: 92.6 %
    # and 88.5 % within 1 ms beside other jobs, 62 % under three busy loops); the replay counts
    # those puts itself. The recording shows no lateness but those (the recorder adds none), most
    # puts are on time, and the messages after a hiccup are on time again: no drift.
    assert statistics.median(err_ms) <= 1.0, summary
    assert over <= late_puts + len(err_ms) // 100, summary
    # Cumulative sleeps would drift by tens of ms over 555 puts; the last ones are on time.
    late_tail = sorted(abs(d - offset) / 1e6 for d in diffs[-50:])
    assert statistics.median(late_tail) <= 1.0, f"replay drifts: {summary}"
    info = inspect(reply.status.path)
    assert info["gaps"] == 0 and info["topics"]["device/gyro"]["count"] == 200


def test_full_disk_alarm_on_status_recorder_stays_up(served_recorder, tmp_path):
    srv = served_recorder(opener=lambda p: FullDisk(p, 300_000), chunk_size_bytes=64 * 1024, flush_period_s=0.05)
    assert srv.command(A.RECORDER_ACTION_START, session="full").ok
    pub = srv.bus.publisher("device/gyro")
    rng = random.Random(5)
    for k in range(400):  # 1.6 MB that lz4 cannot shrink: five times the room on the disk
        m = device_pb2.Gyro()
        m.header.seq = k
        m.header.frame_id = base64.b64encode(rng.randbytes(3000)).decode()
        pub.put(m)
    err = srv.status.wait(lambda s: s.state == S.RECORDER_STATE_ERROR)
    assert "No space left" in err.alarm
    # Still alive and answering; the file is valid up to the failure.
    r = srv.command(A.RECORDER_ACTION_STATUS)
    assert r.ok and r.status.state == S.RECORDER_STATE_ERROR and r.status.alarm == err.alarm
    info = inspect(err.path)
    n = info["topics"]["device/gyro"]["count"]
    assert n > 0 and info["gaps"] == 0 and "_read_error" not in info["metadata"]
    # every message received and then written or dropped (the queue may still hold some when
    # the 400th arrives)
    final = srv.status.wait(
        lambda s: (
            s.topics["device/gyro"].received == 400
            and s.topics["device/gyro"].written + s.topics["device/gyro"].dropped == 400
        )
    )
    c = final.topics["device/gyro"]
    assert c.dropped > 0 and c.written + c.dropped == 400 and n <= c.written


def test_autostart_on_device_streaming_and_commands(served_recorder, tmp_path):
    cal = tmp_path / "cal.yaml"
    cal.write_text("tof_offset_mm: 1.5\n")
    srv = served_recorder(autostart="device", calibration_file=str(cal))
    status_pub = srv.bus.publisher("device/status")
    gyro = srv.bus.publisher("device/gyro")
    status_pub.put(device_pb2.DeviceStatus(state=device_pb2.DEVICE_STATE_CONNECTING, firmware="fw-1.2.3"))
    status_pub.put(
        device_pb2.DeviceStatus(state=device_pb2.DEVICE_STATE_STREAMING, firmware="fw-1.2.3", device_id="d7")
    )
    st = srv.status.wait(lambda s: s.state == S.RECORDER_STATE_RECORDING)
    for k in range(50):
        m = device_pb2.Gyro()
        m.header.seq = k
        gyro.put(m)
    srv.status.wait(lambda s: s.topics["device/gyro"].written == 50)
    assert srv.command(A.RECORDER_ACTION_MARK, "clip applied").ok
    r = srv.command(A.RECORDER_ACTION_SPLIT)
    assert r.ok and r.status.file_index == 1
    assert not srv.command(A.RECORDER_ACTION_START).ok  # already recording
    r = srv.command(A.RECORDER_ACTION_STOP, "end of case")
    assert r.ok and r.status.state == S.RECORDER_STATE_IDLE
    md = read_metadata(st.path)
    assert md["session"]["start_reason"] == "device streaming"
    assert md["device"]["firmware"] == "fw-1.2.3" and md["device"]["device_id"] == "d7"
    assert md["calibration"]["file"] == str(cal)
    assert any(v.get("label") == "clip applied" for k, v in md.items() if k.startswith("event_"))
    info = inspect(st.path)
    assert info["topics"]["device/gyro"]["count"] == 50
    assert info["attachments"] == [
        {"name": "cal.yaml", "media_type": "application/yaml", "bytes": len(cal.read_bytes())}
    ]
