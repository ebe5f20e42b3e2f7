"""`tiplog export`: a bench session's estimate as a LeRobot v3.0 dataset (read back with pyarrow
against the format's layout: lerobot itself needs torch < 2.11), a Slicer sequence file (read
back by SimpleITK's MetaIO reader and by the project's own), JIGSAWS-style CSV; bad input is one
line, exit 2, nothing written."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from tests.conftest import ROOT
from tests.services.fusion.sessions import bench_estimate, bench_session
from tiplog.cli import main as tiplog_main
from tiplog.export.slicer import read_sequence
from tiplog.geometry import quat_to_rot
from tiplog.mcap_io import McapWriter, raw_messages, read_messages, read_metadata

FPS = 30


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """(session with one event mark in its middle and a vision preview at 15 Hz whose grey level
    numbers each image, its estimate, {stamp_ns: FusionState}, preview stamps)."""
    session = bench_session(tmp_path_factory)
    stamps = sorted(
        int(r.message.header.stamp_ns)
        for r in read_messages(bench_estimate(tmp_path_factory, session), ["fusion/state"])
    )
    marked = tmp_path_factory.mktemp("export") / "marked.mcap"
    with McapWriter(marked) as w:
        for name, rec in read_metadata(session).items():
            w.add_metadata(name, rec)
        w.add_metadata("event_0001", {"label": "second half", "log_time_ns": str(stamps[len(stamps) // 2])})
        for schema, channel, msg in raw_messages(session):
            w.write_raw(channel.topic, schema.name, msg.data, msg.log_time)
        previews = np.arange(stamps[0] + 20_000_000, stamps[-1], 1e9 / 15).astype(np.int64)
        for i, t in enumerate(previews):
            ok, jpg = cv2.imencode(".jpg", np.full((48, 64, 3), _grey(i), np.uint8))
            m = CompressedImage(frame_id="camera", format="jpeg", data=jpg.tobytes())
            m.timestamp.FromNanoseconds(int(t))
            w.write("vision/preview", m, int(t) + 120_000_000)  # logged after processing, as live
    est = marked.with_name("est.mcap")
    assert tiplog_main(["fusion", "run", str(marked), "--out", str(est), "--quiet"]) == 0
    states = {int(r.message.header.stamp_ns): r.message for r in read_messages(est, ["fusion/state"])}
    return marked, est, states, previews


def _grey(i: int) -> int:
    return 8 + 9 * (i % 26)  # levels 9 apart, none repeated within 26 images


def _export(*args: str) -> None:
    assert tiplog_main(["export", *args]) == 0


def _state9(s) -> np.ndarray:
    o = s.orientation
    return np.float32([s.tip_m.x, s.tip_m.y, s.tip_m.z, o.x, o.y, o.z, o.w, s.depth_mm, s.roll_deg])


def test_lerobot_v3_dataset_one_episode_per_segment(files, tmp_path):
    session, est, states, previews = files
    out = tmp_path / "ds"
    _export("lerobot", str(session), "--estimate", str(est), "--segments", "events", "--out", str(out))
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == FPS
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    data = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    assert set(data) == {k for k, f in info["features"].items() if f["dtype"] != "video"}  # videos live in mp4
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        assert info["features"][key]["shape"] == [1]
    assert info["features"]["observation.state"]["shape"] == [9]
    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    tasks = pq.read_table(out / "meta/tasks.parquet").to_pydict()
    assert tasks["task_index"] == [0] and eps["tasks"][0] == tasks["__index_level_0__"]
    # The event mark cuts the session in two: two episodes, every frame counted once.
    assert info["total_episodes"] == len(eps["episode_index"]) == 2
    n = len(data["index"])
    assert info["total_frames"] == n == sum(eps["length"])
    assert eps["dataset_from_index"] == [0, eps["length"][0]] and eps["dataset_to_index"][-1] == n
    assert data["index"] == list(range(n))
    print(f"\nlerobot: {info['total_episodes']} episodes, {n} frames ({eps['length']})")
    stamps = np.array(data["observation.stamp_ns"], np.int64)
    ep = np.array(data["episode_index"])
    for e, (a, b) in enumerate(zip(eps["dataset_from_index"], eps["dataset_to_index"], strict=True)):
        assert np.all(ep[a:b] == e)
        fi = np.array(data["frame_index"][a:b])
        assert np.array_equal(fi, np.arange(b - a))
        ts = np.array(data["timestamp"][a:b], np.float64)
        assert np.max(np.abs(ts - fi / FPS)) < 1e-4  # LeRobot's default tolerance_s
        # each row's state was published within half a frame of its grid time
        grid = stamps[a] + (fi / FPS * 1e9)
        assert np.max(np.abs(stamps[a:b] - grid)) <= 1e9 / FPS / 2 + 1
        assert np.all(np.diff(stamps[a:b]) > 0)
    # A state row equals the estimate at its time (float32), the action is the next state.
    state = np.array(data["observation.state"], np.float32)
    action = np.array(data["action"], np.float32)
    for i in (0, n // 3, n - 1):
        est = _state9(states[int(stamps[i])])
        np.testing.assert_array_equal(state[i][[0, 1, 2, 7, 8]], est[[0, 1, 2, 7, 8]])
        q = state[i][3:7]
        assert np.array_equal(q, est[3:7]) or np.array_equal(q, -est[3:7])  # one rotation, sign kept continuous
    q = state[:, 3:7].astype(np.float64)
    for a, b in zip(eps["dataset_from_index"], eps["dataset_to_index"], strict=True):
        assert np.all(np.einsum("ij,ij->i", q[a + 1 : b], q[a : b - 1]) > 0)
    np.testing.assert_array_equal(action[5], state[6])
    np.testing.assert_array_equal(action[eps["dataset_to_index"][0] - 1], state[eps["dataset_to_index"][0] - 1])
    stats = json.loads((out / "meta/stats.json").read_text())
    assert np.allclose(stats["observation.state"]["mean"], state.mean(0), atol=1e-4)
    assert stats["observation.state"]["count"] == [n]
    assert np.allclose(eps["stats/observation.state/min"][0], state[: eps["length"][0]].min(0), atol=1e-6)
    # The preview as video: one frame per row, each the image at or before the row's state.
    key = "observation.images.vision_preview"
    assert info["features"][key]["dtype"] == "video" and info["features"][key]["shape"] == [48, 64, 3]
    video = out / info["video_path"].format(video_key=key, chunk_index=0, file_index=0)
    assert eps[f"videos/{key}/from_timestamp"][1] == eps["dataset_from_index"][1] / FPS
    cap = cv2.VideoCapture(str(video))
    greys = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        greys.append(float(frame.mean()))
    assert len(greys) == n
    expect = [_grey(max(int(np.searchsorted(previews, t, side="right")) - 1, 0)) for t in stamps]
    # MPEG-4 shifts a flat grey by a few levels; neighbouring images differ by 9: the nearest level names the image
    levels = np.array(sorted({_grey(i) for i in range(len(previews))}))
    seen = levels[np.argmin(np.abs(np.array(greys)[:, None] - levels[None, :]), axis=1)]
    assert np.array_equal(seen, expect)
    assert len(stats[key]["mean"]) == 3


def test_slicer_sequence_read_by_simpleitk(files, tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    session, est, states, _ = files
    out = tmp_path / "tool.seq.mha"
    _export("slicer", str(session), "--estimate", str(est), "--out", str(out))
    reader = sitk.ImageFileReader()
    reader.SetFileName(str(out))
    reader.ReadImageInformation()
    n = reader.GetSize()[2]
    keys = set(reader.GetMetaDataKeys())
    assert reader.GetSize()[:2] == (1, 1) and f"Seq_Frame{n - 1:04d}_Timestamp" in keys
    assert f"Seq_Frame{n:04d}_Timestamp" not in keys
    print(f"\nslicer: {n} frames")
    ts = np.array([float(reader.GetMetaData(f"Seq_Frame{k:04d}_Timestamp")) for k in range(n)])
    np.testing.assert_allclose(np.diff(ts), 1 / FPS, atol=1e-6)
    k = n // 2
    assert reader.GetMetaData(f"Seq_Frame{k:04d}_ToolToReferenceTransformStatus") == "OK"
    st = states[int(reader.GetMetaData(f"Seq_Frame{k:04d}_StampNs"))]
    T = np.array(reader.GetMetaData(f"Seq_Frame{k:04d}_ToolToReferenceTransform").split(), float).reshape(4, 4)
    np.testing.assert_allclose(T[:3, 3], np.array([st.tip_m.x, st.tip_m.y, st.tip_m.z]) * 1e3, rtol=0, atol=1e-9)
    q = st.orientation
    np.testing.assert_allclose(T[:3, :3], quat_to_rot(np.array([q.x, q.y, q.z, q.w])), atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [st.shaft_direction.x, st.shaft_direction.y, st.shaft_direction.z], atol=1e-9)
    assert "Seq_Frame0000_TrocarToReferenceTransform" in keys  # the session's calibration
    own = read_sequence(out)
    assert len(own.timestamps_s) == n
    np.testing.assert_array_equal(own.transforms["ToolToReference"][k], T)
    assert own.status_ok["TipToReference"].all()


def test_csv_jigsaws_columns(files, tmp_path):
    session, est, states, _ = files
    out = tmp_path / "kin.csv"
    _export("csv", str(session), "--estimate", str(est), "--out", str(out), "--fps", "0")
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == len(states)  # --fps 0: every state
    r = rows[100]
    st = states[int(r["stamp_ns"])]
    assert float(r["tool_pos_x_m"]) == st.tip_m.x and float(r["depth_mm"]) == st.depth_mm
    R = np.array([[float(r[f"tool_rot_{i}{j}"]) for j in (1, 2, 3)] for i in (1, 2, 3)])
    np.testing.assert_allclose(R[:, 2], [st.shaft_direction.x, st.shaft_direction.y, st.shaft_direction.z], atol=1e-9)
    assert r["tool_gripper_angle_rad"] == "" and r["valid"] == "1"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "export", *args], cwd=ROOT, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120,
    )  # fmt: skip


def _one_line_exit_2(p: subprocess.CompletedProcess, *words: str) -> None:
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_input_one_line_exit_2_nothing_written(files, tmp_path, tmp_path_factory):
    session, est, _, _ = files
    before = set(tmp_path.iterdir())
    _one_line_exit_2(_cli("rosbag", str(session), "--out", str(tmp_path / "x")), "invalid choice", "rosbag")
    # an estimate of another recording (the session before its preview and mark were added)
    other = bench_session(tmp_path_factory)
    _one_line_exit_2(
        _cli("csv", str(other), "--estimate", str(est), "--out", str(tmp_path / "x.csv")), "another recording"
    )
    # the bench session alone holds no fusion state
    _one_line_exit_2(
        _cli("slicer", str(session), "--out", str(tmp_path / "x.seq.mha")), "no fusion state", "tiplog fusion run"
    )
    assert set(tmp_path.iterdir()) == before
    existing = tmp_path / "old.csv"
    existing.write_text("keep me\n")
    _one_line_exit_2(_cli("csv", str(session), "--estimate", str(est), "--out", str(existing)), "exists", "--force")
    _one_line_exit_2(_cli("slicer", str(session), "--estimate", str(est), "--out", str(existing)), "exists", "--force")
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "mine.txt").write_text("keep me\n")
    _one_line_exit_2(_cli("lerobot", str(session), "--estimate", str(est), "--out", str(ds)), "exists", "--force")
    assert existing.read_text() == "keep me\n" and [p.name for p in ds.iterdir()] == ["mine.txt"]
    assert set(tmp_path.iterdir()) == before | {existing, ds}  # no partial file left behind
