"""`tiplog up` restarts a service killed with SIGKILL and says so on `system/supervisor`; the
banner says where to look; after Ctrl-C the recording in progress is a valid MCAP file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest

from services.bench.app import BenchConfig, write_calibration
from tests.conftest import ROOT, free_port
from tiplog.bus import Bus, BusConfig
from tiplog.mcap_io import read_summary
from tiplog.v1 import recorder_pb2, system_pb2

pytestmark = pytest.mark.slow
R = system_pb2.ServiceRunState


def test_kill_9_is_restarted_reported_and_the_recording_stays_valid(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "up.yaml"
    cfg.write_text(
        f"recorder:\n  out_dir: {tmp_path}/rec\n  autostart: always\n  min_free_bytes: 0\ndashboard:\n  port: {free_port()}\n"
    )
    calibration = tmp_path / "calibration.yaml"
    write_calibration(BenchConfig(scenario="static", calibration_file=str(calibration)))
    up = subprocess.Popen(
        [sys.executable, "-m", "tiplog.cli", "up", "--listen", ep, "-c", str(cfg), "--services", "recorder,fusion"]
        + ["--calibration", str(calibration)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    statuses: list[system_pb2.SupervisorStatus] = []
    supervisor_written = threading.Event()  # the recording holds at least one supervisor status
    cv = threading.Condition()

    def on_status(msg, _info) -> None:
        with cv:
            statuses.append(msg)
            cv.notify_all()

    def on_recorder(msg, _info) -> None:
        counts = msg.topics.get("system/supervisor")
        if msg.state == recorder_pb2.RECORDER_STATE_RECORDING and counts is not None and counts.written > 0:
            supervisor_written.set()

    def wait_for(pred, timeout=60.0):
        with cv:
            assert cv.wait_for(lambda: any(pred(s) for s in statuses), timeout), statuses[-1:] or "no status"
            return next(s for s in statuses if pred(s))

    def run_of(st, name):
        return next(r for r in st.services if r.service == name)

    try:
        with Bus(BusConfig(mode="client", connect=[ep], listen=[])) as bus:
            bus.subscribe("system/supervisor", on_status)
            bus.subscribe("recorder/status", on_recorder)
            first = wait_for(lambda s: run_of(s, "fusion").state == R.SERVICE_RUN_STATE_RUNNING)
            pid = run_of(first, "fusion").pid
            os.kill(pid, signal.SIGKILL)
            died = wait_for(lambda s: "fusion killed by SIGKILL" in s.event)
            assert run_of(died, "fusion").state == R.SERVICE_RUN_STATE_RESTARTING
            assert run_of(died, "recorder").state == R.SERVICE_RUN_STATE_RUNNING  # the others keep running
            back = wait_for(lambda s: run_of(s, "fusion").restarts == 1 and run_of(s, "fusion").pid not in (0, pid))
            assert run_of(back, "fusion").state == R.SERVICE_RUN_STATE_RUNNING
            # Ctrl-C only once the recorder, which may start slowly on a loaded machine, is recording
            assert supervisor_written.wait(60), "the recorder never wrote a supervisor status"
        up.send_signal(signal.SIGINT)
        out, err = up.communicate(timeout=30)
        assert up.returncode == 0, err
    finally:
        if up.poll() is None:
            up.kill()
    assert "recordings  " in out and f"{tmp_path}/rec" in out and "Ctrl-C" in out
    (rec,) = (tmp_path / "rec").glob("*.mcap")
    summary = read_summary(rec)
    assert summary is not None  # closed with its summary on Ctrl-C
    assert any(c.topic == "system/supervisor" for c in summary.channels.values())
