"""live_budget's per-second table and its targets, from made-up events (no system runs here)."""

from __future__ import annotations

import pytest

from benchmarks.live_budget import Seconds, _given_up, _per_second, demo_config, main
from tiplog.loadstatus import LoadMeter
from tiplog.v1 import fusion_pb2, system_pb2

S = 1_000_000_000


def test_each_second_counts_what_happened_in_it_and_the_targets_follow():
    acc = Seconds()
    acc.t0_ns = 10 * S
    acc.add("state", 9 * S, 30.0)  # before the measurement: left out
    for k in range(3):
        for i in range(200 if k != 1 else 150):
            acc.add("gyro", acc.t0_ns + k * S + i * 5_000_000)
            acc.add("state", acc.t0_ns + k * S + i * 5_000_000, 31.0)
        for i in range(12):
            acc.add("vision", acc.t0_ns + k * S + i * 80_000_000, 120.0)
        for i in range(30):
            acc.add("display_lag", acc.t0_ns + k * S + i * 33_000_000, 40.0 if k != 2 else 90.0)
        d = fusion_pb2.FusionDiagnostics(resets=0)
        d.updates["reacquire"] = 1 if k == 2 else 0
        d.innovation_nis["vision_axis"] = 5.0
        acc.samples["fusion/diagnostics:msg"][k].append(d)
        m = LoadMeter("vision", 15.0)
        m.counts["frames_dropped_stale"] = 3 * k
        acc.samples["vision/status:msg"][k].append(m.status(k * S))
    r = _per_second(acc, 3)
    rows, s = r["per_second"], r["summary"]
    assert [x["state_hz"] for x in rows] == [200, 150, 200] and [x["gyro_hz"] for x in rows] == [200, 150, 200]
    assert [x["vision_hz"] for x in rows] == [12, 12, 12]
    assert [x["vision_dropped_stale"] for x in rows] == [0, 3, 3]  # per second, from the running count
    assert [x["reacquisitions"] for x in rows] == [0, 0, 1]
    assert s["seconds_under_195"] == 1 and s["reacquisitions"] == 1 and s["vision_dropped_stale"] == 6
    t = s["targets"]
    assert not t["fusion >= 195 Hz every second"] and not t["no re-acquisition or reset"]
    assert not t["display lag p95 <= 50 ms"]  # a third of the states at 90 ms
    assert t["vision >= 10 obs/s"] and t["vision latency p95 <= 250 ms"] and t["vision-axis NIS within x2 of 4"]


def test_the_device_wait_is_against_the_quickest_sample_of_the_seconds_around():
    acc = Seconds()
    acc.t0_ns = 10 * S
    offset_ms = 5_000.0  # the device clock's offset from the host's: cancels
    for k in range(30):
        for i in range(200):
            t = acc.t0_ns + k * S + i * 5_000_000
            late = 300.0 if k == 20 and i < 20 else 2.0 + 0.001 * k  # a held-up burst; a drifting clock
            acc.add("device_wait", t, offset_ms + late)
    rows = _per_second(acc, 30)["per_second"]
    assert rows[5]["device_wait_p95_ms"] == pytest.approx(0.0, abs=0.02)
    assert rows[20]["device_wait_p95_ms"] == pytest.approx(298.0, abs=0.1)  # 20 of 200 samples 298 ms late
    assert rows[29]["device_wait_p95_ms"] == pytest.approx(0.0, abs=0.02)  # drift cancelled by the window


def test_the_demo_configuration_moves_only_where_it_runs(tmp_path):
    cfg = demo_config(tmp_path, fresh=True)
    assert cfg["bench"]["camera_tier"] == "pixel" and cfg["bench"]["scenario"] == "demo"
    assert cfg["sensor_gateway"]["port"] == cfg["bench"]["device_link"] == str(tmp_path / "device")
    assert cfg["dashboard"]["foxglove_bridge"] and cfg["dashboard"]["port"] != 8000
    assert cfg["bench"]["pass_cache_dir"] == str(tmp_path / "pass-cache")
    assert "pass_cache_dir" not in demo_config(tmp_path, fresh=False)["bench"]


def test_bad_arguments_are_one_line_and_exit_2(capsys):
    for argv, line in [
        (["--seconds", "0"], "live_budget: --seconds must be above 0 (got 0)"),
        (["--set", "vision.workers"], "live_budget: --set wants SECTION.FIELD=VALUE (got 'vision.workers')"),
        (["--set", "workers=1"], "live_budget: --set wants SECTION.FIELD=VALUE (got 'workers=1')"),
    ]:
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        assert capsys.readouterr().err.splitlines() == [line]


def test_a_service_given_up_on_ends_the_run_with_its_error():
    R = system_pb2.ServiceRunState
    st = system_pb2.SupervisorStatus()
    st.services.add(service="bench", state=R.SERVICE_RUN_STATE_RUNNING)

    class Up:
        def latest_status(self):
            return st

    _given_up(Up())  # all running: nothing to say
    st.services.add(
        service="fusion", state=R.SERVICE_RUN_STATE_FAILED, last_error="config error: fusion: no calibration"
    )
    with pytest.raises(RuntimeError, match=r"^fusion given up on: config error: fusion: no calibration$"):
        _given_up(Up())
