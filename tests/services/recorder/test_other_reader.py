"""A recording read by another MCAP implementation: the TypeScript one (@mcap/core, as in
Foxglove), with protobuf decoding from the schemas embedded in the file.

The node packages are pinned in mcap_node/package-lock.json and installed by `make test`
(`npm ci` in that folder); without node, or without the installed packages, the test skips
and says why."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from foxglove_schemas_protobuf import RawImage_pb2

from services.recorder.config import RecorderConfig
from services.recorder.recorder import Recorder
from tiplog.bus import SampleInfo
from tiplog.mcap_io import read_messages
from tiplog.v1 import device_pb2, recorder_pb2

NODE_DIR = Path(__file__).parent / "mcap_node"
A = recorder_pb2.RecorderAction


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the TypeScript MCAP reader cannot run (install node >= 18)")
    if not (NODE_DIR / "node_modules" / "@mcap" / "core").is_dir():
        pytest.skip(f"@mcap/core not installed: run `npm ci` in {NODE_DIR} (make test does)")
    return node


def _record(path_dir: Path, compression: str) -> Path:
    rec = Recorder(
        RecorderConfig(
            out_dir=str(path_dir),
            autostart="never",
            min_free_bytes=0,
            compression=compression,
            chunk_size_bytes=256 * 1024,
            camera_archive="raw",  # the frames as RawImage, read back by the other reader
        )
    )
    rec.start_thread()
    assert rec.command(recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_START, session=compression)).ok
    t = 2_000_000_000
    for k in range(400):
        t += 5_000_000
        g = device_pb2.Gyro()
        g.header.seq, g.header.stamp_ns = k, t
        g.rate_radps.z = 0.01 * k
        rec.on_sample(g.SerializeToString(), SampleInfo("device/gyro", k, t - 100, t, 1, "tiplog.v1.Gyro"))
        if k % 13 == 0:
            img = RawImage_pb2.RawImage(width=64, height=48, encoding="rgb8", step=192, data=bytes(range(256)) * 36)
            img.timestamp.FromNanoseconds(t)
            rec.on_sample(
                img.SerializeToString(), SampleInfo("camera/image", k // 13, t, t + 1, 2, "foxglove.RawImage")
            )
    assert rec.command(recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_MARK, reason="event")).ok
    assert rec.command(recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_STOP)).ok
    rec.close()
    return path_dir / f"{compression}_000.mcap"


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_typescript_reader_reads_the_recording(tmp_path, compression):
    node = _node()
    path = _record(tmp_path, compression)
    out = subprocess.run(
        [node, str(NODE_DIR / "read_mcap.mjs"), str(path)], capture_output=True, text=True, timeout=60, cwd=NODE_DIR
    )
    assert out.returncode == 0, out.stderr
    ts = json.loads(out.stdout)
    py: dict[str, int] = {}
    for r in read_messages(path):
        py[r.topic] = py.get(r.topic, 0) + 1
    assert {t: v["count"] for t, v in ts["topics"].items()} == py
    assert ts["topics"]["device/gyro"]["schema"] == "tiplog.v1.Gyro"
    assert ts["topics"]["camera/image"]["schema"] == "foxglove.RawImage"
    assert ts["topics"]["device/gyro"]["example"]["stamp_ns"] == "2005000000"
    assert ts["topics"]["camera/image"]["example"] == {"width": 64, "height": 48, "encoding": "rgb8"}
    assert ts["topics"]["device/gyro"]["last_sequence"] == 399
    assert ts["topics"]["device/gyro"]["compression"] == [compression]
    assert ts["message_count"] == sum(py.values()) and ts["chunk_count"] > 1 and ts["log_time_ordered"]
    assert {"session", "configuration", "recorder_counts", "event_0001"} <= set(ts["metadata"])
