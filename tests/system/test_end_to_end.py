"""The whole system on the simulated bench for over 60 s under `tiplog up` (bench live with the
measurement-tier camera, gateway on the emulated device through a pty, fusion, recorder,
dashboard; each its own process on a loopback router): the recording holds every stream at
its rate with no drops, the live tip error against the bench truth is within 1.5x of
`tiplog fusion run` on the same recording, and the dashboard serves the state.

The pixel tier with the real vision service is left to `benchmarks.system_soak --tier pixel`:
on a shared 2-core machine it does not render at 15 fps beside everything else.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.system.analysis import (
    NOMINAL_HZ,
    read_track,
    rms,
    status_changes,
    supervisor_periodic,
    tip_error_mm,
    topic_rates,
)
from tests.system.harness import UpRun
from tiplog.mcap_io import read_summary

# realtime: every stream's rate within 5 % of nominal over the minute, a wall-clock figure; beside
# three other workers on two cores fusion's worker stalled 3.8 s once (diagnostics at 1.74 Hz)
pytestmark = [pytest.mark.slow, pytest.mark.realtime]

SERVICES = ["bench", "sensor_gateway", "fusion", "recorder", "dashboard"]
RECORD_S = 62.0
SETTLE_S = 10.0  # the filter's start (initialisation, first vision fixes) left out of the error


def test_whole_system_60s_rates_live_vs_offline_and_dashboard(tmp_path):
    with UpRun(tmp_path, SERVICES) as up:
        up.wait_status(up.all_running, timeout_s=120)
        # The first fusion state on the page starts the clock of the run.
        first = up.poll_api("/api/state", lambda a: a["received"] > 0 and a["state"] is not None, 120)
        t0_ns = first["state"]["header"]["stamp_ns"]
        # Until the page shows a state 62 s of bench time later (the bench's stamps, not the wall).
        later = up.poll_api(
            "/api/state", lambda a: a["state"]["header"]["stamp_ns"] - t0_ns > RECORD_S * 1e9, RECORD_S * 3 + 60
        )
        health = up.api("/api/health")
        assert later["received"] > 100 * RECORD_S  # the page receives states at the gyro rate
        assert later["age_s"] < 1.0  # and the newest is fresh
        assert np.isfinite(later["derived"]["err_mm"])
        for name in SERVICES:
            assert health["services"][name]["state"] == "up", health["services"]
        assert up.stop() == 0, up.log_tail()

    (rec,) = up.recordings()
    assert read_summary(rec) is not None  # closed with its summary on Ctrl-C
    rates = topic_rates(rec)
    assert not [t for t in rates if t.startswith("_rejected/")], rates  # the system's own messages all pass
    for topic, hz in NOMINAL_HZ.items():
        r = rates[topic]
        assert r.seq_gaps == 0, (topic, r)
        if topic == "vision/observation":
            # One per camera frame while the shaft is in view: the demo's path leaves it for
            # seconds at a time (stamps skip, sequence numbers do not).
            assert 0.75 * hz < r.rate_hz < 1.05 * hz, (topic, r)
        elif topic == "device/status":
            # One per status period, and one more at once on every change of state: the
            # bench's link closing and the gateway stopping as the system stops are recorded
            # too (the recorder stops last), so those are left out of the period's rate.
            changes = status_changes(rec)
            assert changes >= 1  # at least the stop
            periodic_hz = r.rate_hz * (r.count - 1 - changes) / (r.count - 1)
            assert abs(periodic_hz - hz) < 0.05 * hz, (topic, r, changes)
        elif topic == "system/supervisor":
            # One per second, and one more at once on every start, exit and restart, and the
            # events held until the recorder was up, published again as it comes up
            periodic = supervisor_periodic(rec)
            assert abs(periodic.rate_hz - hz) < 0.05 * hz, (topic, r, periodic)
        else:
            assert abs(r.rate_hz - hz) < 0.05 * hz, (topic, r)
    assert rates["device/gyro"].count > 200 * RECORD_S

    truth = read_track(rec, "bench/robot")
    live = read_track(rec, "fusion/state")
    # Ctrl-C stops the recorder last, so the file holds what fusion published as it stopped:
    # the settled stream's last second (it runs max_age_ms behind) reaches the display's end.
    settled = read_track(rec, "fusion/state_settled")
    assert settled.stamp_ns[-1] >= live.stamp_ns[-1] - 50_000_000, (settled.stamp_ns[-1], live.stamp_ns[-1])
    offline_path = tmp_path / "offline.mcap"
    subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "fusion", "run", str(rec), "--out", str(offline_path), "--quiet"],
        cwd=ROOT,
        check=True,
        timeout=300,
    )
    offline = read_track(offline_path, "fusion/state")
    t0 = max(live.stamp_ns[0], offline.stamp_ns[0]) + int(SETTLE_S * 1e9)
    t1 = min(live.stamp_ns[-1], offline.stamp_ns[-1])
    assert t1 - t0 > 45e9
    err_live = tip_error_mm(live, truth, t0, t1)
    err_offline = tip_error_mm(offline, truth, t0, t1)
    assert len(err_live) > 0.95 * 200 * (t1 - t0) / 1e9  # the live filter kept up with the gyro
    assert rms(err_live) <= 1.5 * rms(err_offline), (rms(err_live), rms(err_offline))
    assert rms(err_offline) < 10.0  # a tracking filter, not a frozen one

    # The start-up transient the dashboard engineer saw (depths up to 3.9 m): the live depth
    # stays within 20 mm of the bench's range from the first state on. Still seen on some runs
    # (seed 1: 224 states in the first 1.1 s at 0.68-4.03 m, one 'innovation' reset), and
    # `tiplog fusion run` on the same recording repeats it state for state: the filter's start.
    lo, hi = truth.depth_mm.min(), truth.depth_mm.max()
    assert live.depth_mm.min() > lo - 20 and live.depth_mm.max() < hi + 20, (live.depth_mm.min(), live.depth_mm.max())
