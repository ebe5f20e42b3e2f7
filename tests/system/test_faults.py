"""Faults under `tiplog up` with real processes (kill -9 of each service is
`test_kill_each.py`):

- kill -9 of `tiplog up` itself: every service notices its supervisor is gone and stops
  cleanly (the recording in progress closed, valid), nothing is left running, and a new
  `tiplog up` on the same endpoint, port and device link starts;
- kill -9 of the recorder: the supervisor's events while no recorder recorded (its death, its
  restart) are in the next file with their original stamps, and that file's data resumes."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from tests.system.harness import UpRun, system_config
from tiplog.mcap_io import read_messages, read_summary
from tiplog.v1 import recorder_pb2

pytestmark = pytest.mark.slow

SERVICES = ["bench", "sensor_gateway", "recorder", "dashboard"]


def _gone(pid: int) -> bool:
    """Exited (a zombie counts: it runs nothing and holds nothing)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True
    return "\nState:\tZ" in status


def test_kill_9_of_up_stops_every_service_cleanly_and_a_new_up_starts(tmp_path):
    config = system_config(tmp_path)
    up = UpRun(tmp_path, SERVICES, config=config)
    with up:
        st = up.wait_status(up.all_running, timeout_s=120)
        pids = {n: up.run_of(st, n).pid for n in SERVICES}
        recording = threading.Event()

        def on_status(msg: recorder_pb2.RecorderStatus, _info) -> None:
            if msg.path and msg.topics["device/gyro"].written > 100:
                recording.set()

        up.bus.subscribe("recorder/status", on_status)
        assert recording.wait(90), "the recorder never wrote gyro samples"
        os.kill(up.proc.pid, signal.SIGKILL)
        up.proc.wait(10)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not all(_gone(p) for p in pids.values()):
            time.sleep(0.1)
        left = {n: p for n, p in pids.items() if not _gone(p)}
        assert not left, f"still running after the supervisor died: {left}"
    recs = up.recordings()
    assert len(recs) == 1
    assert read_summary(recs[0]) is not None, "the recorder did not close its file"
    assert sum(1 for _ in read_messages(recs[0], ["device/gyro"])) > 0

    again = UpRun(tmp_path, SERVICES, config=config)
    again.endpoint = up.endpoint  # the same router endpoint, dashboard port and device link
    with again:
        again.wait_status(again.all_running, timeout_s=120)
        again.poll_api("/api/health", lambda a: a["services"].get("bench", {}).get("state") == "up", 60)
        assert again.stop() == 0, again.log_tail()


def test_kill_9_of_the_recorder_hands_its_events_to_the_next_file(tmp_path):
    services = ["bench", "sensor_gateway", "recorder"]
    with UpRun(tmp_path, services) as up:
        st = up.wait_status(up.all_running, timeout_s=120)
        recording = threading.Event()
        paths: set[str] = set()

        def on_status(msg: recorder_pb2.RecorderStatus, _info) -> None:
            if msg.path and msg.topics["device/gyro"].written > 100:
                paths.add(msg.path)
                recording.set()

        up.bus.subscribe("recorder/status", on_status)
        assert recording.wait(90), "the recorder never wrote gyro samples"
        first = set(paths)
        os.kill(up.run_of(st, "recorder").pid, signal.SIGKILL)
        killed = up.wait_status(lambda s: "recorder killed by SIGKILL" in s.event and not s.replayed, 30)
        recording.clear()
        deadline = time.monotonic() + 60
        while not (paths - first) and time.monotonic() < deadline:
            recording.wait(0.5)
        assert paths - first, "no new file after the recorder's restart"
        up.wait_status(lambda s: s.replayed and "recorder killed by SIGKILL" in s.event, 30)
        assert up.stop() == 0, up.log_tail()
    *_, last = up.recordings()
    sup = [r for r in read_messages(last, ["system/supervisor"])]
    replayed = [r for r in sup if r.message.replayed]
    events = [r.message.event for r in replayed]
    assert any("recorder killed by SIGKILL" in e for e in events), events
    assert any("recorder restarted" in e for e in events), events
    death = next(r for r in replayed if "recorder killed by SIGKILL" in r.message.event)
    assert death.message.header.stamp_ns == killed.header.stamp_ns  # its original stamp
    gyro = [r.log_time_ns for r in read_messages(last, ["device/gyro"])]
    assert gyro and death.message.header.stamp_ns < gyro[0]  # it happened before this file began
