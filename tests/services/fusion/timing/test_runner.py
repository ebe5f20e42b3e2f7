"""FusionRunner on a short bench session: the output depends only on the inputs (not on how
advance() interleaves with feed()), rewinding equals in-order application, a too-old frame is
counted and dropped, corrupt or non-finite input never reaches the output, and a diverged
filter resets itself from vision."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from services.fusion.eskf.params import Params
from services.fusion.live.publish import to_diagnostics
from services.fusion.timing.runner import ALL, FusionRunner
from study.evaluation import interp_columns as _truth_at
from tests.services.fusion.sessions import bench_session, inputs
from tiplog.calibration import Calibration
from tiplog.mcap_io import read_messages, read_metadata


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = bench_session(tmp_path_factory)
    calib = Calibration.from_mcap_metadata(read_metadata(path))
    truth = [(r.message.header.stamp_ns, r.message.tip_m) for r in read_messages(path, ["bench/robot"])]
    t = np.array([s for s, _ in truth])
    tip = np.array([[p.x, p.y, p.z] for _, p in truth])
    return inputs(path), calib, (t, tip)


def _arrays(samples):
    return np.array([s.stamp_ns for s in samples]), np.array([s.p_tip_base_m for s in samples])


def _gyro_fault(msgs, seconds: float, radps: float):
    """(the inputs with `radps` added to the gyro's z for `seconds` from a third of the way in,
    the fault's start)."""
    t_mid = msgs[len(msgs) // 3][2]
    spoilt = []
    for t, m, a in msgs:
        if t == "device/gyro" and t_mid <= a < t_mid + seconds * 1e9:
            m = copy.deepcopy(m)
            m.rate_radps.z += radps
        spoilt.append((t, m, a))
    return spoilt, t_mid


def _run(msgs, calib, params=None, schedule="offline", rng=None, output="display"):
    r = FusionRunner(calib, params or Params(), output=output)
    out = []
    for topic, msg, arr in msgs:
        r.feed(topic, msg, arr)
        if schedule == "every":
            out += r.advance(arr)
        elif schedule == "random" and rng.random() < 0.05:
            out += r.advance(arr)
    out += r.finish()
    return out, r


def test_output_depends_only_on_inputs(session):
    msgs, calib, (tt, tip) = session
    off, r_off = _run(msgs, calib)
    live, _ = _run(msgs, calib, schedule="every")
    rnd, _ = _run(msgs, calib, schedule="random", rng=np.random.default_rng(3))
    t0, p0 = _arrays(off)
    assert len(off) > 1000 and r_off.diagnostics()["rewinds"] > 10  # late vision did rewind
    for other in (live, rnd):
        t1, p1 = _arrays(other)
        np.testing.assert_array_equal(t0, t1)
        np.testing.assert_array_equal(p0, p1)
    assert np.all(np.diff(t0) > 0)  # each state exactly once, in order
    # and it tracks: tip within a few mm of the robot after the first seconds
    late = t0 > t0[0] + 3e9
    truth = _truth_at(t0[late], tt, tip)
    assert np.sqrt(np.mean(np.sum((p0[late] - truth) ** 2, 1))) < 4e-3


def test_rewind_equals_in_order_application(session):
    msgs, calib, _ = session
    prm = Params(history_ms=60_000.0, max_age_ms=1000.0)
    late, r_late = _run(msgs, calib, prm)
    # the same measurements, each arriving at its own (latency-corrected) time: no rewinds
    lat = {k: calib.latency_ns(k) for k in ("gyro", "accel", "tof", "camera")}
    stream = {"device/gyro": "gyro", "device/accel": "accel", "device/tof": "tof", "vision/observation": "camera"}
    prompt = sorted(
        ((t, m, m.header.stamp_ns - lat[stream[t]] if t in stream else a) for t, m, a in msgs), key=lambda x: x[2]
    )
    _, r_prompt = _run(prompt, calib, prm)
    assert r_late.diagnostics()["rewinds"] > 10 and r_prompt.diagnostics()["rewinds"] == 0
    h_late, h_prompt = r_late.history(), r_prompt.history()
    t0, p0 = _arrays(h_late)
    t1, p1 = _arrays(h_prompt)
    np.testing.assert_array_equal(t0, t1)
    np.testing.assert_allclose(p0, p1, rtol=0, atol=1e-12)
    assert r_late.diagnostics()["updates"] == r_prompt.diagnostics()["updates"]
    # published (provisional) states lacked the frames still in flight: not the same
    assert not np.array_equal(_arrays(late)[1], p0[-len(late) :])


def test_settled_output_is_the_revised_trajectory_without_rewinds(session):
    """output="settled" (what `tiplog fusion run` writes) is every state once each late frame
    has been applied at its time; "both" (the live service) gives the display stream unchanged
    and the same settled states beside it; the settled ones are nearer the robot."""
    msgs, calib, (tt, tip) = session
    display, r_display = _run(msgs, calib)
    settled, r_settled = _run(msgs, calib, output="settled")
    r_both = FusionRunner(calib, output="both")
    shown, kept = [], []
    for topic, msg, arr in msgs:
        r_both.feed(topic, msg, arr)
        if topic == "device/gyro":
            shown += r_both.advance(arr)
            kept += r_both.take_settled()
    shown += r_both.finish()
    kept += r_both.take_settled()
    assert r_settled.diagnostics()["rewinds"] == 0 and r_both.diagnostics()["rewinds"] > 10
    assert r_settled.history() == [] and len(r_both.history()) > 100  # settled keeps no snapshots
    for a, b in ((shown, display), (kept, settled)):
        (ta, pa), (tb, pb) = _arrays(a), _arrays(b)
        np.testing.assert_array_equal(ta, tb)
        np.testing.assert_allclose(pa, pb, rtol=0, atol=1e-12)
    assert r_settled.diagnostics()["lag_ms"] == 1000.0 and r_display.diagnostics()["lag_ms"] == 30.0
    (t_d, p_d), (t_s, p_s) = _arrays(display), _arrays(settled)
    late = t_s > t_s[0] + 3e9
    common = np.isin(t_s, t_d) & late
    assert common.sum() > 1000
    on_display = np.isin(t_d, t_s[common])
    truth = _truth_at(t_s[common], tt, tip)
    err_s = np.sqrt(np.mean(np.sum((p_s[common] - truth) ** 2, 1)))
    err_d = np.sqrt(np.mean(np.sum((p_d[on_display] - truth) ** 2, 1)))
    assert err_s < err_d, (err_s, err_d)
    with pytest.raises(ValueError, match="output must be one of"):
        FusionRunner(calib, output="live")


def test_too_old_frame_counted_and_dropped(session):
    msgs, calib, _ = session
    base, r0 = _run(msgs, calib)
    i = next(k for k, (t, m, _) in enumerate(msgs) if t == "vision/observation" and m.accepted and k > len(msgs) // 2)
    stale = copy.deepcopy(msgs[i][1])
    arrival = msgs[i][2] + 1_500_000_000  # 1.5 s late: beyond max_age_ms
    extra = sorted([*msgs, ("vision/observation", stale, arrival)], key=lambda x: x[2])
    out, r1 = _run(extra, calib)
    assert r1.diagnostics()["rejected"].get("vision:too_old", 0) == 1
    assert r0.diagnostics()["rejected"].get("vision:too_old", 0) == 0
    np.testing.assert_array_equal(_arrays(base)[1], _arrays(out)[1])


def test_tips_held_for_confirmation_are_counted_in_the_diagnostics(session):
    """A surprising vision tip waits for the next frame: the diagnostics count those held
    (`deferred`) apart from those refused, and carry them into fusion/diagnostics."""
    msgs, calib, _ = session
    _, r_default = _run(msgs, calib)
    _, r_eager = _run(msgs, calib, Params(tip_confirm_chi2=0.02))  # most tips now surprise
    d_default, d_eager = r_default.diagnostics(), r_eager.diagnostics()
    held = d_eager["deferred"].get("vision_tip", 0)
    assert held > 10 and held > d_default["deferred"].get("vision_tip", 0)
    # a held tip is confirmed (the next one applied) or dropped: never applied itself
    assert d_eager["updates"]["vision_tip"] < d_default["updates"]["vision_tip"]
    assert d_eager["rejected"].get("vision_tip:unconfirmed", 0) > 0
    msg = to_diagnostics(d_eager, stamp_ns=1)
    assert dict(msg.deferred) == {"vision_tip": held}


def test_corrupt_and_non_finite_inputs_never_reach_the_output(session):
    msgs, calib, _ = session
    bad = []
    n_bad = 0
    for k, (t, m, a) in enumerate(msgs):
        bad.append((t, m, a))
        if t == "device/gyro" and k % 97 == 0:
            nan = copy.deepcopy(m)
            nan.rate_radps.x = float("nan")
            bad.append((t, nan, a))
        elif t == "device/accel" and k % 89 == 0:
            bad.append((t, object(), a))  # not a message at all
        elif t == "vision/observation" and m.accepted and k % 7 == 0:
            inf = copy.deepcopy(m)
            inf.junction_ray.z = float("inf")  # every vector is checked, the junction ray too
            bad.append((t, inf, a))
        else:
            continue
        n_bad += 1
    out, r = _run(bad, calib)
    assert n_bad > 10 and r.diagnostics()["corrupt"] == n_bad
    p = _arrays(out)[1]
    assert len(p) > 1000 and np.isfinite(p).all()


def _deeper_junctions(msgs, calib, n: int, mm: float):
    """(the inputs with the first n frames' junction rays moved `mm` deeper along the shaft their
    own start would take, those frames' stamps)."""
    r = FusionRunner(calib, Params())
    f = r.filt
    out, stamps = [], []
    for topic, msg, arr in msgs:
        if topic == "vision/observation" and len(stamps) < n and msg.accepted and msg.junction_visible:
            cand = f.init_from_vision(0, r.adapter.measurement(topic, msg).value, None)
            if cand is not None:
                u_c = f.A @ cand.R[:, 2]
                J = f.A @ (cand.p - f.c_cam) - f.jp * u_c + mm * 1e-3 * u_c
                msg = copy.deepcopy(msg)
                msg.junction_ray.x, msg.junction_ray.y, msg.junction_ray.z = J / np.linalg.norm(J)
                stamps.append(msg.header.stamp_ns)
        out.append((topic, msg, arr))
    return out, stamps


def test_a_start_waits_for_a_frame_the_tof_agrees_with(session):
    """The runner hands the latest range to the filter's start: the session's first frames with
    their junctions 25 mm too deep start nothing while the ToF is there; without the ToF the
    first of them starts the filter, 25 mm off."""
    msgs, calib, (tt, tip) = session
    spoilt, stamps = _deeper_junctions(msgs, calib, 5, 25.0)
    assert len(stamps) == 5
    for sensors, first_after in ((ALL, True), (frozenset({"imu", "vision"}), False)):
        r = FusionRunner(calib, Params(), sensors)
        out = []
        for topic, msg, arr in spoilt:
            r.feed(topic, msg, arr)
            out += r.advance(arr)
        out += r.finish()
        first = out[0]
        err = np.linalg.norm(first.p_tip_base_m - _truth_at(np.array([first.stamp_ns]), tt, tip)[0])
        refused = r.diagnostics()["rejected"].get("start:tof_disagrees", 0)
        if first_after:
            assert first.stamp_ns > stamps[-1] - calib.latency_ns("camera") and err < 8e-3
            assert refused >= len(stamps) - 1  # the first frame may come before the first accelerometer sample
        else:
            assert first.stamp_ns < stamps[-1] and err > 15e-3
            assert refused == 0


def test_divergence_resets_from_vision(session):
    msgs, calib, (tt, tip) = session
    spoilt, _ = _gyro_fault(msgs, 1.0, 3.0)  # a 1 s gyro fault: 3 rad/s that never happened
    out, r = _run(spoilt, calib)
    d = r.diagnostics()
    assert d["resets"] >= 1, d
    # the counts cover the whole run, not only the state since the last reset: about as many
    # RCM updates as the same run without the fault (the fault's second itself has fewer)
    clean = _run(msgs, calib)[1].diagnostics()
    assert d["updates"]["rcm"] > 0.8 * clean["updates"]["rcm"], (d["updates"], clean["updates"])
    assert 0.0 < d["nis"]["rcm"] < 10.0
    t, p = _arrays(out)
    assert np.isfinite(p).all()
    end = t > t[-1] - 1.5e9  # recovered by the end
    truth = _truth_at(t[end], tt, tip)
    assert np.sqrt(np.mean(np.sum((p[end] - truth) ** 2, 1))) < 5e-3


def test_a_reset_without_vision_restarts_from_the_imu_and_tof(session):
    """Vision gone for good and then a reset: the filter restarts from the IMU and ToF after
    restart_without_vision_ms instead of publishing nothing to the end; 0 waits for vision."""
    msgs, calib, (tt, tip) = session
    spoilt, t_mid = _gyro_fault(msgs, 1.0, 3.0)
    blind = [e for e in spoilt if e[0] != "vision/observation" or e[2] < t_mid]
    t_gyro = [a for topic, _, a in blind if topic == "device/gyro"]
    out, r = _run(blind, calib)
    d = r.diagnostics()
    assert d["resets"] >= 1, d
    assert d["updates"]["restart_without_vision"] == d["resets"], d  # each reset here restarted so
    assert not d["vision_locked"]
    t, p = _arrays(out)
    assert np.isfinite(p).all()
    gaps = np.diff(t)
    assert 0.9e9 <= gaps.max() <= 1.2e9  # the wait, not the rest of the session
    assert t[-1] > t_gyro[-1] - 0.2e9  # published to the end
    after = t > t[np.argmax(gaps)]
    depth = np.linalg.norm(p[after] - calib.rcm_base_m, axis=1)
    assert ((depth >= 0.02 - 1e-9) & (depth <= 0.40 + 1e-9)).all()
    waited, r0 = _run(blind, calib, Params(restart_without_vision_ms=0.0))
    t0, _ = _arrays(waited)
    assert r0.diagnostics()["resets"] >= 1 and t0[-1] < t_mid + 1.5e9  # nothing after the reset
    assert "restart_without_vision" not in r0.diagnostics()["updates"]


def test_a_reset_forgets_what_the_tof_map_learnt_from_the_diverging_state(session):
    """The map records range errors against the filter's own pose; what it took from a state
    going wrong (after the last vision tip it accepted) would bend the depth in later blackouts."""
    msgs, calib, (tt, tip) = session
    spoilt, t_mid = _gyro_fault(msgs, 0.5, 1.5)  # fast enough to go wrong before vision rejects it
    _, r = _run(spoilt, calib)
    assert r.diagnostics()["resets"] >= 1
    t, keys, _ = r.filt.tof_map.entries()
    assert len(t) > 100
    truth = _truth_at(t, tt, tip)
    off = np.linalg.norm(keys[:, 9:12] - truth, axis=1)  # each entry's recorded tip against the truth
    assert off.max() < 0.005, (off.max(), t[np.argmax(off)] - t_mid)


def test_a_backlog_stamped_nanoseconds_apart_does_not_throw_the_tip(session):
    """A stalled host: nothing for 0.7 s, then the gateway stamps the backlog 1 ns apart (it
    never stamps a sample at or before the previous one). The lever arm's angular acceleration
    over nanoseconds once threw the tip kilometres away for over a second, in the system test."""
    msgs, calib, (tt, tip) = session
    t_stall = msgs[len(msgs) // 2][2]
    t_back = t_stall + 700_000_000
    out_msgs, backlog = [], {}
    for t, m, a in msgs:
        if t.startswith("device/") and t_stall <= a < t_back:
            backlog.setdefault(t, []).append(m)
            continue
        if a >= t_back and backlog:  # the backlog arrives at once, stamped 1 ns apart
            for topic, ms in backlog.items():
                for k, mm in enumerate(ms):
                    mm = copy.deepcopy(mm)
                    mm.header.stamp_ns = t_back + k
                    out_msgs.append((topic, mm, t_back + k))
            backlog = {}
        out_msgs.append((t, m, a))
    out, r = _run(out_msgs, calib)
    t, p = _arrays(out)
    truth = _truth_at(t, tt, tip)
    err_mm = np.linalg.norm(p - truth, axis=1) * 1e3
    assert len(out) > 1000 and np.isfinite(p).all()
    assert err_mm.max() < 50.0, (err_mm.max(), r.diagnostics()["reset_reasons"])


def test_vision_before_the_device_streams_starts_sane(session):
    """Live, the bench's vision can reach fusion before the gateway has opened the device: the
    filter must not start from a frame with no accelerometer sample (roll unknown, so gravity
    would be removed along the wrong axis and the tip would run off by metres)."""
    msgs, calib, (tt, tip) = session
    t_dev = msgs[0][2] + 1_500_000_000  # the device streams begin 1.5 s after vision
    late_device = [(t, m, a) for t, m, a in msgs if t == "vision/observation" or a >= t_dev]
    out, r = _run(late_device, calib)
    t, p = _arrays(out)
    assert len(out) > 1000
    truth = _truth_at(t, tt, tip)
    err_mm = np.linalg.norm(p - truth, axis=1) * 1e3
    assert err_mm.max() < 30.0, (err_mm.max(), r.diagnostics()["resets"])
    assert r.diagnostics()["resets"] == 0


def test_a_start_without_vision_takes_the_working_depth_it_is_given(session):
    """Without vision the range cannot tell depth from heading: the filter starts at, and then
    holds, the working depth `start_depth_mm` (140 mm unless told)."""
    msgs, calib, _ = session
    blind = [e for e in msgs if e[0] != "vision/observation"]
    depth = {}
    for mm in (140.0, 170.0):
        r = FusionRunner(calib, Params(start_depth_mm=mm), sensors=frozenset({"imu", "tof"}))
        out = []
        for topic, msg, arr in blind:
            r.feed(topic, msg, arr)
        out += r.finish()
        _, p = _arrays(out)
        depth[mm] = np.linalg.norm(p - calib.rcm_base_m, axis=1) * 1e3
    for mm, d in depth.items():
        assert abs(d[0] - mm) < 1.0, (mm, d[0])
        assert abs(np.median(d) - mm) < 10.0, (mm, np.median(d))  # the working depth holds it
    assert np.median(depth[170.0]) - np.median(depth[140.0]) > 20.0
