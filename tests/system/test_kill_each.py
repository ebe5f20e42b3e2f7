"""kill -9 each service in turn while `tiplog up` runs the whole system: the supervisor
restarts it, the others keep running (same pid, no restart), the page's health
(GET /api/health, liveliness) shows it down and then up again, the page's status counts the
restart, and the recording (across the recorder's own restart) stays valid."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import ROOT
from tests.system.harness import R, UpRun
from tiplog.mcap_io import read_messages, read_summary

pytestmark = pytest.mark.slow

# The dashboard goes last: while it is down nobody answers /api/health.
SERVICES = ["bench", "sensor_gateway", "fusion", "recorder", "vision", "dashboard"]


def _health_state(up: UpRun, name: str):
    return lambda a: a["services"].get(name, {}).get("state")


def test_kill_9_each_service_in_turn(tmp_path):
    with UpRun(tmp_path, SERVICES) as up:
        st = up.wait_status(up.all_running, timeout_s=150)
        up.poll_api("/api/health", lambda a: all(a["services"].get(n, {}).get("state") == "up" for n in SERVICES), 150)
        up.poll_api("/api/state", lambda a: a["received"] > 400, 150)  # the bench streams, fusion tracks
        pids = {n: up.run_of(st, n).pid for n in SERVICES}
        for k, name in enumerate(SERVICES):
            t_kill = time.monotonic()
            os.kill(pids[name], signal.SIGKILL)
            died = up.wait_status(lambda s, name=name: f"{name} killed by SIGKILL" in s.event, 30)
            for other in SERVICES:
                if other != name:  # the others keep running, untouched
                    run = up.run_of(died, other)
                    assert run.state == R.SERVICE_RUN_STATE_RUNNING and run.pid == pids[other], (other, run)
            if name != "dashboard":  # the page shows it down (its liveliness token is gone), or already
                # back with a token newer than the kill (the recorder is restarted at once)
                up.poll_api(
                    "/api/health",
                    lambda a, name=name, t=t_kill: (
                        a["services"][name]["state"] == "down" or a["services"][name]["since_s"] < time.monotonic() - t
                    ),
                    30,
                )
            back = up.wait_status(
                lambda s, name=name: (
                    up.run_of(s, name).restarts == 1
                    and up.run_of(s, name).state == R.SERVICE_RUN_STATE_RUNNING
                    and up.run_of(s, name).pid not in (0, pids[name])
                ),
                60,
            )
            pids[name] = up.run_of(back, name).pid
            # ... and up again, its restart counted on the page
            up.poll_api("/api/health", lambda a, name=name: a["services"][name]["state"] == "up", 90)
            status = up.poll_api("/api/status", lambda a, name=name: a["health"][name].get("restarts") == 1, 30)
            assert sum(h.get("restarts", 0) for h in status["health"].values()) == k + 1
        # After all that, states still flow to the page.
        n0 = up.api("/api/state")["received"]
        up.poll_api("/api/state", lambda a: a["received"] > n0 + 200, 60)
        assert up.stop() == 0, up.log_tail()

    recs = up.recordings()
    assert len(recs) >= 2  # the recorder's restart starts a new file; the killed one is left as it was
    *killed, last = recs
    assert read_summary(last) is not None  # the one in progress at Ctrl-C is closed validly
    topics = {r.topic for r in read_messages(last)}
    assert {"device/gyro", "fusion/state", "system/supervisor"} <= topics
    for path in killed:  # cut short by SIGKILL: `tiplog record recover` makes it whole
        fixed = path.with_suffix(".recovered.mcap")
        subprocess.run(
            [sys.executable, "-m", "tiplog.cli", "record", "recover", str(path), "--out", str(fixed)],
            cwd=ROOT,
            check=True,
            capture_output=True,
            timeout=120,
        )
        assert read_summary(fixed) is not None
        assert sum(1 for _ in read_messages(fixed, ["device/gyro"])) > 0, path
