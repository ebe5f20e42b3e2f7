"""The dashboard's skill-metrics route over the trail it holds, on a real Zenoh session."""

from __future__ import annotations

import numpy as np
import pytest

from tests.services.dashboard.conftest import VIEWER, make_robot, make_state
from tests.services.fusion.sessions import bench_geometry
from tiplog.clock import now_ns


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    return bench_geometry(tmp_path_factory)[0]


def test_metrics_of_the_trail_beside_the_reference(served, calibration):
    with served.client(VIEWER) as c:
        assert c.get("/api/metrics").status_code == 409  # no calibration yet: no RCM
        assert c.get("/api/metrics").json()["detail"].startswith("no calibration")
    served.running.feed.calibration = calibration
    rcm = calibration.rcm_base_m
    u = np.array([0.4, 0.0, -np.sqrt(1 - 0.16)])
    fusion = served.pub_bus.publisher("fusion/state")
    robot = served.pub_bus.publisher("bench/robot")
    t0 = now_ns()
    before, refs = served.running.feed.state.total, served.running.feed.reference.total
    n = 600  # 3 s at 200 Hz: the tip inserted 30 mm along the shaft at 10 mm/s
    for k in range(n):
        tip = rcm + (0.13 + 0.01 * k / 200) * u
        robot.put(make_robot(t0 + k * 5_000_000, tip.tolist(), rcm.tolist()))
        fusion.put(make_state(t0 + k * 5_000_000, tip_m=(tip + [0.0005, 0.0, 0.0]).tolist()))
    served.wait_states(before + n)
    served.wait_states(refs + n, ring="reference")
    with served.client(VIEWER) as c:
        r = c.get("/api/metrics", params={"download": 1})
    assert r.status_code == 200 and "attachment" in r.headers["content-disposition"]
    body = r.json()
    assert body["recording"] is None and body["end_s"] - body["start_s"] == pytest.approx(2.995, abs=0.01)
    m, truth = body["metrics"], body["truth"]
    assert m["path_length_mm"] == pytest.approx(30.0, rel=0.05)
    assert m["depth_path_mm"] == pytest.approx(30.0, rel=0.05)
    assert m["economy_straight"] == pytest.approx(1.0, abs=0.02)
    assert truth["path_length_mm"] == pytest.approx(30.0, rel=0.05)
    assert m["mean_speed_mmps"] == pytest.approx(truth["mean_speed_mmps"], rel=0.01)
