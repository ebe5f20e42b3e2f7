"""`tiplog fusion run` and `tiplog evaluate` as a user meets them: bad input gives one line
and exit 2, never a traceback or an overwritten file; the estimate is identical, bit for bit,
when the bench's truth is removed from the recording; evaluate's JSON carries the keys other
tools read and its figures follow the error put in."""

from __future__ import annotations

import json

import numpy as np
import pytest

from services.fusion.offline.inputs import announced_rates
from tests.services.fusion.sessions import bench_session, rewrite, sweeps_estimate_fixture, sweeps_session_fixture  # noqa: F401 (fixtures session, estimate)
from tiplog.calibration import Calibration
from tiplog.cli import main as tiplog_main
from tiplog.mcap_io import McapWriter, read_messages, read_metadata

ESTIMATOR_META = {"calibration_as_calibrated"}


def _fails(capsys, argv, *needles):
    code = tiplog_main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], err[0]


def test_bad_inputs_one_line_exit_2(tmp_path, capsys, session, estimate):
    out = str(tmp_path / "o.mcap")
    _fails(capsys, ["fusion", "run", str(tmp_path / "none.mcap"), "--out", out], "no such")
    txt = tmp_path / "x.mcap"
    txt.write_text("hello")
    _fails(capsys, ["fusion", "run", str(txt), "--out", out], "not an MCAP")
    _fails(capsys, ["fusion", "run", str(session), "--out", str(estimate)], "exists", "--force")
    _fails(capsys, ["fusion", "run", str(session), "--out", out, "--sensors", "imu,radar"], "radar")
    bad = tmp_path / "p.yaml"
    bad.write_text("tof_sigma: 3\n")
    _fails(capsys, ["fusion", "run", str(session), "--out", out, "--params", str(bad)], "tof_sigma")
    bad.write_text("tof_map_sigma_deg: 0\n")  # a zero kernel width would divide by zero
    _fails(capsys, ["fusion", "run", str(session), "--out", out, "--params", str(bad)], "tof_map_sigma_deg", "> 0")
    nocal = tmp_path / "nocal.mcap"
    rewrite(session, nocal, lambda t: True, lambda n: n == "session")
    _fails(capsys, ["fusion", "run", str(nocal), "--out", out], "no calibration")
    noimu = tmp_path / "noimu.mcap"
    rewrite(session, noimu, lambda t: not t.startswith("device/"), lambda n: True)
    _fails(capsys, ["fusion", "run", str(noimu), "--out", out], "no IMU")
    sparse = tmp_path / "sparse.mcap"  # gyro at a fifth of its rate
    with McapWriter(sparse) as w:
        for name, rec in read_metadata(session).items():
            w.add_metadata(name, rec)
        for r in read_messages(session):
            if r.topic != "device/gyro" or r.message.header.seq % 5 == 0:
                w.write(r.topic, r.message, r.log_time_ns)
    _fails(capsys, ["fusion", "run", str(sparse), "--out", out], "device/gyro", "nominal 200", "announced")
    _fails(
        capsys,
        ["evaluate", str(session), "--estimate", str(session), "--json", str(tmp_path / "r.json")],
        "no estimate",
    )
    assert not (tmp_path / "o.mcap").exists() and not (tmp_path / "r.json").exists()


def test_a_slow_vision_stream_is_processed_with_a_warning(tmp_path, session, capfd):
    """Vision sheds stale frames on a loaded cart by design: a live recording with vision at a
    fifth of its rate is a recording to process (with a warning naming the rate), not one to
    refuse as the IMU's would be."""
    slow = tmp_path / "slow_vision.mcap"
    kept = 0
    with McapWriter(slow) as w:
        for name, rec in read_metadata(session).items():
            w.add_metadata(name, rec)
        for r in read_messages(session):
            if r.topic == "vision/observation":
                kept += 1
                if kept % 5:
                    continue
            w.write(r.topic, r.message, r.log_time_ns)
    out = tmp_path / "o.mcap"
    assert tiplog_main(["fusion", "run", str(slow), "--out", str(out), "--quiet"]) == 0
    assert out.exists()
    err = capfd.readouterr().err
    assert "vision/observation at 3.0 Hz, below its nominal 15 Hz" in err, err


def test_a_module_with_other_rates_is_checked_against_the_rates_it_announced(tmp_path, capsys):
    """A lab's own module (gyro and accelerometer at 100 Hz, ToF at 50) runs: the rates it
    announced (the `device` metadata), not the paper's module's, are the nominal ones."""
    rec = tmp_path / "slow.mcap"
    sets = ["gyro.rate_hz=100", "accel.rate_hz=100", "tof.rate_hz=50"]
    argv = ["sim", "generate", "--scenario", "sweeps", "--seed", "13", "--duration", "6", "--out", str(rec)]
    assert tiplog_main([*argv, *(a for kv in sets for a in ("--set", kv)), "--quiet"]) == 0
    rates = json.loads(read_metadata(rec)["device"]["nominal_rates_hz"])
    assert rates == {"gyro": 100.0, "accel": 100.0, "tof": 50.0, "mag": 100.0}
    out = tmp_path / "est.mcap"
    assert tiplog_main(["fusion", "run", str(rec), "--out", str(out), "--quiet"]) == 0
    t = np.array([r.message.header.stamp_ns for r in read_messages(out, ["fusion/state"])], np.int64)
    assert len(t) > 300 and np.median(np.diff(t)) == pytest.approx(10e6, rel=0.05)  # the gyro's 100 Hz
    unannounced = tmp_path / "unannounced.mcap"
    rewrite(rec, unannounced, lambda topic: True, lambda n: n != "device")
    capsys.readouterr()
    _fails(
        capsys, ["fusion", "run", str(unannounced), "--out", str(tmp_path / "o.mcap")], "device/accel", "nominal 240"
    )
    assert announced_rates({"device": {"nominal_rates_hz": "{not json"}}) == {}  # the defaults, with a warning


def test_estimate_identical_without_truth(tmp_path, session, estimate):
    stripped = tmp_path / "stripped.mcap"
    rewrite(session, stripped, lambda t: not t.startswith("bench/"), lambda n: n in ESTIMATOR_META)
    assert "calibration_truth" not in read_metadata(stripped)
    out = tmp_path / "est2.mcap"
    assert tiplog_main(["fusion", "run", str(stripped), "--out", str(out), "--quiet"]) == 0
    a = [r.message.SerializeToString() for r in read_messages(estimate, ["fusion/state"])]
    b = [r.message.SerializeToString() for r in read_messages(out, ["fusion/state"])]
    assert len(a) > 500 and a == b
    # a calibration file with the same constants gives the same estimate as the metadata
    cal = tmp_path / "cal.yaml"
    Calibration.from_mcap_metadata(read_metadata(session)).save_yaml(cal)
    out3 = tmp_path / "est3.mcap"
    assert tiplog_main(["fusion", "run", str(session), "--out", str(out3), "--calibration", str(cal), "--quiet"]) == 0
    c = [r.message.SerializeToString() for r in read_messages(out3, ["fusion/state"])]
    assert c == a
    md = read_metadata(out3)
    assert json.loads(md["fusion_params"]["json"])["output_delay_ms"] == 30.0
    assert "rcm_base_m" in json.loads(md["fusion_calibration"]["json"])


def test_the_settled_trajectory_by_default_and_the_live_one_on_request(tmp_path, session, estimate):
    """fusion/state is the settled causal filter (`max_age_ms` behind, scoring better); with
    --as-live it is what the live service published (30 ms behind); the metadata say which."""
    live = tmp_path / "live.mcap"
    assert tiplog_main(["fusion", "run", str(session), "--out", str(live), "--as-live", "--quiet"]) == 0
    got = {}
    for name, path in (("settled", estimate), ("display", live)):
        lags = {round(r.message.lag_ms, 6) for r in read_messages(path, ["fusion/state"])}
        assert read_metadata(path)["fusion"]["output"] == name
        res = tmp_path / f"{name}.json"
        assert tiplog_main(["evaluate", str(session), "--estimate", str(path), "--json", str(res)]) == 0
        got[name] = (lags, json.loads(res.read_text())["pooled"]["tip_rmse_mm"])
    assert got["settled"][0] == {1000.0} and got["display"][0] == {30.0}
    assert got["settled"][1] < got["display"][1]
    # a live recording holds both: evaluate scores its settled stream unless told otherwise
    both = tmp_path / "live_recording.mcap"
    with McapWriter(both) as w:
        for r in read_messages(live, ["fusion/state"]):
            w.write("fusion/state", r.message, r.log_time_ns)
        for r in read_messages(estimate, ["fusion/state"]):
            w.write("fusion/state_settled", r.message, r.log_time_ns)
    for topic, want in ((None, "settled"), ("fusion/state", "display")):
        res = tmp_path / "both.json"
        argv = ["evaluate", str(session), "--estimate", str(both), "--json", str(res), "--force"]
        assert tiplog_main(argv + (["--topic", topic] if topic else [])) == 0
        r = json.loads(res.read_text())
        assert r["estimate_topic"] == (topic or "fusion/state_settled")
        assert r["pooled"]["tip_rmse_mm"] == got[want][1]


def test_evaluate_keys_and_figures_follow_the_error(tmp_path, session, estimate):
    res, plots = tmp_path / "r.json", tmp_path / "plots"
    args = ["evaluate", str(session), "--estimate", str(estimate), "--json", str(res), "--plots", str(plots)]
    assert tiplog_main(args) == 0
    r = json.loads(res.read_text())
    assert sorted(f.name for f in plots.iterdir()) == sorted(f"{b['name']}.png" for b in r["blocks"])
    assert all(f.stat().st_size > 5_000 for f in plots.iterdir())
    keys = ("tip_rmse_mm", "tip_median_mm", "tip_p95_mm", "radial_rmse_mm", "tangential_rmse_mm")
    for k in keys:
        assert np.isfinite(r["pooled"][k])
    assert r["blocks"] and all(k in r["blocks"][0] for k in ("name", *keys))
    assert 0.05 < r["pooled"]["tip_rmse_mm"] < 5.0
    # the truth itself as the estimate, shifted 3 mm along base x: error exactly 3 mm
    shifted = tmp_path / "shifted.mcap"
    from tiplog.v1.fusion_pb2 import FusionState

    with McapWriter(shifted) as w:
        for rec in read_messages(session, ["bench/robot"]):
            m = FusionState()
            m.header.stamp_ns = rec.message.header.stamp_ns
            m.tip_m.x, m.tip_m.y, m.tip_m.z = rec.message.tip_m.x + 0.003, rec.message.tip_m.y, rec.message.tip_m.z
            w.write("fusion/state", m, rec.log_time_ns)
    res2 = tmp_path / "r2.json"
    assert tiplog_main(["evaluate", str(session), "--estimate", str(shifted), "--json", str(res2)]) == 0
    p = json.loads(res2.read_text())["pooled"]
    assert p["tip_rmse_mm"] == pytest.approx(3.0, abs=1e-6)
    assert p["radial_rmse_mm"] ** 2 + p["tangential_rmse_mm"] ** 2 == pytest.approx(9.0, abs=1e-6)
    assert 0.5 < p["radial_rmse_mm"] < 2.9  # the shaft is oblique: both parts carry some


def test_evaluate_says_how_much_of_a_block_the_estimate_covers(tmp_path, capsys, session):
    """A filter that published nothing for a while is scored only where it published: the
    coverage says how much that is, and the printout warns."""
    from study.evaluation import block_windows, load_truth
    from tiplog.v1.fusion_pb2 import FusionState

    name, a, b = block_windows(load_truth(session).trials)[0]
    gap = (a + (b - a) // 4, a + 3 * (b - a) // 4)  # half of the first block's scored window
    est = tmp_path / "gap.mcap"
    with McapWriter(est) as w:
        for rec in read_messages(session, ["bench/robot"]):
            t = rec.message.header.stamp_ns
            if gap[0] <= t < gap[1]:
                continue
            m = FusionState()
            m.header.stamp_ns = t
            m.tip_m.x, m.tip_m.y, m.tip_m.z = rec.message.tip_m.x, rec.message.tip_m.y, rec.message.tip_m.z
            w.write("fusion/state", m, rec.log_time_ns)
    res = tmp_path / "r.json"
    capsys.readouterr()
    assert tiplog_main(["evaluate", str(session), "--estimate", str(est), "--json", str(res)]) == 0
    out = capsys.readouterr().out
    r = json.loads(res.read_text())
    first = r["blocks"][0]
    assert first["name"] == name and first["coverage"] == pytest.approx(0.5, abs=0.02)
    assert all(blk["coverage"] > 0.99 for blk in r["blocks"][1:])
    assert r["pooled"]["coverage"] < 0.99
    assert "estimate covers 50 %" in out and "warning" in out


def test_a_recording_longer_than_the_device_streams_is_run(tmp_path, capsys, session):
    """The recorder runs before the bench or the module starts (seconds under load) and after
    it stops: the file's span holds other topics beyond the device's. Each stream's rate is
    taken over its own span, so such a file is not refused as "far off its nominal" (a live
    recording under load was)."""
    late = tmp_path / "long.mcap"
    records = list(read_messages(session))
    t1 = max(r.log_time_ns for r in records)
    other = next(r for r in records if r.topic == "bench/robot")
    with McapWriter(late) as w:
        for name, rec in read_metadata(session).items():
            w.add_metadata(name, rec)
        for r in records:
            w.write(r.topic, r.message, r.log_time_ns)
        w.write(other.topic, other.message, t1 + 20_000_000_000)  # 20 s after the device's last sample
    out = tmp_path / "est.mcap"
    assert tiplog_main(["fusion", "run", str(late), "--out", str(out), "--quiet"]) == 0
    a = [r.message.SerializeToString() for r in read_messages(out, ["fusion/state"])]
    ref = tmp_path / "ref.mcap"
    capsys.readouterr()
    assert tiplog_main(["fusion", "run", str(session), "--out", str(ref)]) == 0  # with progress, into no terminal
    assert "\r" not in capsys.readouterr().err  # a redirected log gets no in-place progress line
    assert a == [r.message.SerializeToString() for r in read_messages(ref, ["fusion/state"])] and len(a) > 100
