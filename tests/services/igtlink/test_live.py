"""The OpenIGTLink service live over a bench session, against pyigtl's client in another
process: transforms at the configured rate, equal to fusion/state's tip and shaft within
float32 rounding, stamps in the header version 2 metadata, INVALID while fusion is not
tracking, and reconnection after the client or the service restarts."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, free_port
from tests.services.fusion.sessions import bench_estimate, bench_session
from tiplog.bus import Bus
from tiplog.calibration import Calibration
from tiplog.geometry import quat_to_rot
from tiplog.mcap_io import read_messages, read_metadata

pytest.importorskip("pyigtl")

RATE_HZ = 50.0
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _service(endpoint: str, prefix: str, port: int, calibration: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "services.igtlink", "--connect", endpoint, "--prefix", prefix]
    for s in (f"port={port}", f"rate_hz={RATE_HZ}", "stale_after_s=0.2", "status_period_s=0.5"):
        cmd += ["--set", s]
    cmd += ["--set", f"calibration_file={calibration}"]
    return subprocess.Popen(cmd, cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _client(port: int, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "tests.helpers.igtl_client", "127.0.0.1", str(port), str(out)]
    return subprocess.Popen(cmd, cwd=ROOT, env=ENV)


def _rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def _wait_rows(path: Path, pred, timeout: float = 30.0) -> list[dict]:
    """Rows of `path` once one satisfies `pred` (polled: the client is another process)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rows = _rows(path)
        if any(pred(r) for r in rows):
            return rows
        time.sleep(0.05)
    raise AssertionError(f"no matching message in {path} within {timeout} s ({len(_rows(path))} rows)")


def _invalid(r: dict) -> bool:
    return r["type"] == "TRANSFORM" and r["metadata"].get("TransformStatus") == "INVALID"


def _not_tracking(r: dict) -> bool:
    return r["type"] == "STRING" and r["string"].startswith("NOT_TRACKING")


def _valid(r: dict) -> bool:
    return r["type"] == "TRANSFORM" and r["metadata"].get("TransformStatus") == "OK"


def _publish(pub, states: list, seconds: float) -> None:
    """fusion/state at the gyro rate (200 Hz) for `seconds`, paced on the monotonic clock."""
    n = min(len(states), int(seconds * 200))
    t0 = time.monotonic()
    for i, s in enumerate(states[:n]):
        due = t0 + i / 200.0
        if (d := due - time.monotonic()) > 0:
            time.sleep(d)
        pub.put(s)


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_slicer_client_gets_the_estimate_live(tmp_path_factory, tmp_path, bus_pair_configs):
    session = bench_session(tmp_path_factory)
    states = [r.message for r in read_messages(bench_estimate(tmp_path_factory, session), ["fusion/state"])]
    by_stamp = {int(s.header.stamp_ns): s for s in states}
    calibration = Calibration.from_mcap_metadata(read_metadata(session))
    calib_file = tmp_path / "calibration.yaml"
    calibration.save_yaml(calib_file)
    listen_cfg, _ = bus_pair_configs
    port = free_port()
    out1, out2 = tmp_path / "client1.jsonl", tmp_path / "client2.jsonl"
    with Bus(listen_cfg) as bus:
        pub = bus.publisher("fusion/state")
        svc = _service(listen_cfg.listen[0], listen_cfg.prefix, port, calib_file)
        client = _client(port, out1)
        try:
            # Before any state: INVALID transforms (identity, never a pose) and the STRING status.
            rows = _wait_rows(out1, _not_tracking)
            inv = [r for r in rows if _invalid(r)]
            assert {r["device"] for r in inv} == {"TipToReference", "ToolToReference", "TrocarToReference"}
            assert all(np.allclose(r["matrix"], np.eye(4)) for r in inv)
            assert not any(_valid(r) for r in rows)

            n0 = len(_rows(out1))
            _publish(pub, states, 2.0)
            rows = _wait_rows(out1, _not_tracking, timeout=10)[n0:]  # fusion stopped: not tracking again
            valid = [r for r in rows if _valid(r)]
            tips = [r for r in valid if r["device"] == "TipToReference"]
            tools = [r for r in valid if r["device"] == "ToolToReference"]
            trocars = [r for r in valid if r["device"] == "TrocarToReference"]
            assert len(tips) == len(tools) == len(trocars) > 20
            assert all(r["header_version"] == 2 for r in valid)
            # The rate: one state per tick, so consecutive stamps are 1/rate apart; never faster.
            stamps = np.array([int(r["metadata"]["StampNs"]) for r in tips])
            assert np.all(np.diff(stamps) > 0)
            spacing_ms = float(np.median(np.diff(stamps))) * 1e-6
            assert 0.8 * 1e3 / RATE_HZ <= spacing_ms <= 1.25 * 1e3 / RATE_HZ, spacing_ms
            print(f"\nreceived {len(tips)} tip transforms over 2.0 s; median stamp spacing {spacing_ms:.2f} ms")
            # Values: fusion/state's tip [mm] and shaft within float32 rounding, stamp carried.
            for tip, tool in zip(tips, tools, strict=True):
                st = by_stamp[int(tip["metadata"]["StampNs"])]
                assert tool["metadata"]["StampNs"] == tip["metadata"]["StampNs"]
                p_mm = np.float32(np.array([st.tip_m.x, st.tip_m.y, st.tip_m.z]) * 1e3)
                np.testing.assert_array_equal(np.float32(np.array(tip["matrix"])[:3, 3]), p_mm)
                np.testing.assert_array_equal(np.float32(np.array(tool["matrix"])[:3, 3]), p_mm)
                np.testing.assert_array_equal(np.array(tip["matrix"])[:3, :3], np.eye(3))
                q = st.orientation
                R = np.array(tool["matrix"])[:3, :3]
                np.testing.assert_allclose(R, quat_to_rot(np.array([q.x, q.y, q.z, q.w])), rtol=0, atol=2e-7)
                u = np.array([st.shaft_direction.x, st.shaft_direction.y, st.shaft_direction.z])
                np.testing.assert_allclose(R[:, 2], u, rtol=0, atol=1e-6)  # z of the tool frame: the shaft
                assert tip["metadata"]["VisionLocked"] == ("true" if st.vision_locked else "false")
                sig = [float(v) for v in tip["metadata"]["TipSigmaMm"].split()]
                np.testing.assert_allclose(sig, [st.tip_sigma_mm.x, st.tip_sigma_mm.y, st.tip_sigma_mm.z], rtol=1e-5)
            np.testing.assert_allclose(
                np.array(trocars[0]["matrix"])[:3, 3], calibration.rcm_base_m * 1e3, rtol=0, atol=1e-3
            )

            # The client restarts: a new connection gets the status at once, then poses again.
            _stop(client)
            client = _client(port, out2)
            _wait_rows(out2, _not_tracking)
            _publish(pub, states[400:], 0.5)
            _wait_rows(out2, _valid, timeout=10)

            # The service restarts on its port: the same client reconnects and gets poses again.
            _stop(svc)
            assert svc.returncode == 0, svc.stderr.read()
            n2 = len(_rows(out2))
            svc = _service(listen_cfg.listen[0], listen_cfg.prefix, port, calib_file)
            deadline = time.monotonic() + 60
            while not any(_valid(r) for r in _rows(out2)[n2:]):
                assert time.monotonic() < deadline, "the client never got a pose from the restarted service"
                _publish(pub, states[:40], 0.2)
        finally:
            _stop(client)
            _stop(svc)
