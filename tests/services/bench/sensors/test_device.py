"""Sensor models against their parameters, on analytic ground truth (seeded; tolerances
from the sample sizes)."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.scenario import load_scenario
from services.bench.sensors import device as sensors
from services.bench.sensors.calibration import true_constants
from services.bench.sensors.pose_field import PoseField, ou_process
from tests.services.bench.synthetic_truth import pivot
from tiplog.geometry import so3_exp
from tiplog.v1.device_pb2 import TofStatus

QUIET = {
    "gyro.bias_rw_static_dps_rts": 0.0,
    "gyro.bias_rw_motion_dps_rts_per_radps": 0.0,
    "gyro.scale_sd": 0.0,
    "accel.noise_pose_spread": 0.0,
    "tof.noise_pose_spread": 0.0,
}


def _setup(overrides=None, duration_s=20.0, angle=None, axis=None):
    sc = load_scenario("static", {**QUIET, **(overrides or {})})
    const = true_constants(sc)
    R0 = sc.motion.R_neutral()
    gt = pivot(R0, const.rcm_base_m, 0.14, duration_s, axis, angle)
    return sc, const, gt


def test_rest_gyro_noise_and_accel_gravity():
    sc, const, gt = _setup()
    kin, clock, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(1))
    g = st["gyro"]
    n = len(g)
    assert abs(n - 20 * 200) <= 2
    sd = np.radians(sc.gyro.noise_density_dps_rthz) * np.sqrt(sc.gyro.rate_hz)
    got = (g.values - g.values.mean(0)).std(0)
    np.testing.assert_allclose(got, sd, rtol=4 / np.sqrt(2 * n))
    a = st["accel"]
    g_imu = (gt.R_base_tool[0] @ const.R_tool_imu).T @ np.array([0, 0, 9.80665])
    # mean: gravity in the IMU frame up to the pose-locked tilt (0.21 deg) and bias
    ang = np.degrees(np.arccos(a.values.mean(0) @ g_imu / np.linalg.norm(a.values.mean(0)) / 9.80665))
    assert ang < 1.0
    np.testing.assert_allclose(
        (a.values - a.values.mean(0)).std(0), sc.accel.noise_sd_mps2, rtol=4 / np.sqrt(2 * len(a))
    )


def test_tilt_sd_per_sample_in_papers_range():
    sc, const, gt = _setup({"accel.noise_pose_spread": 0.5})  # clipped to the paper's range
    _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(2))
    v = st["accel"].values
    e = v.mean(0) / np.linalg.norm(v.mean(0))
    b1 = np.cross(e, [1.0, 0, 0])
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(e, b1)
    vn = v / np.linalg.norm(v, axis=1, keepdims=True)
    tilt = np.degrees(np.sqrt(0.5 * ((vn @ b1).var() + (vn @ b2).var())))
    assert 0.30 <= tilt <= 0.55


def test_lever_arm_pure_rotation_about_rcm():
    """Rotation about the RCM with angle(t) = a t^2/2 + w0 t: the IMU's specific force is
    R^T (alpha x r + w x (w x r) - g), r from the RCM to the IMU."""
    alpha, w0 = 0.5, 0.3
    axis = np.array([0.0, 1.0, 0.0])
    sc, const, gt = _setup(duration_s=2.0, angle=lambda t: 0.5 * alpha * t**2 + w0 * t, axis=axis)
    kin = sensors.kinematics(gt, const)
    k = np.arange(200, 1800)
    w = (w0 + alpha * gt.t_ns[k] * 1e-9)[:, None] * axis
    p_imu = gt.p_tip_base_m[k] + gt.R_base_tool[k] @ const.p_imu_tool_m
    r = p_imu - gt.rcm_base_m
    a = np.cross(alpha * axis, r) + np.cross(w, np.cross(w, r))
    R_imu = gt.R_base_tool[k] @ const.R_tool_imu
    f_expected = np.einsum("nji,nj->ni", R_imu, a - sensors.G_BASE)
    np.testing.assert_allclose(kin.f_imu_mps2[k], f_expected, atol=2e-4)
    # body rate in the tool frame: R^T w
    w_tool = np.einsum("nji,nj->ni", gt.R_base_tool[k], w)
    np.testing.assert_allclose(kin.omega_tool_radps[k], w_tool, atol=1e-6)
    # the centripetal term alone has the size w^2 |r| (|r| = 0.304 - 0.14 m plus the lateral offset)
    assert np.linalg.norm(np.cross(w[0], np.cross(w[0], r[0]))) == pytest.approx(
        np.linalg.norm(w[0]) ** 2 * np.linalg.norm(r[0] - (r[0] @ axis) * axis), rel=1e-9
    )


def test_latency_and_clock():
    sc, const, gt = _setup(duration_s=30.0)
    _, clock, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(3))
    for name, cfg in (("gyro", sc.gyro), ("accel", sc.accel), ("tof", sc.tof), ("mag", sc.mag)):
        s = st[name]
        lat = (s.arrival_ns - s.t_true_ns) * 1e-6
        assert lat.mean() == pytest.approx(cfg.latency_ms, abs=0.05)
        assert lat.std() == pytest.approx(cfg.latency_jitter_ms, rel=0.15)
        assert np.all(np.diff(s.arrival_ns) > 0)
        period = np.diff(s.device_ns)
        assert np.all(np.abs(period - 1e9 / cfg.rate_hz) <= 1)  # device ticks at its nominal rate
        assert np.all(s.device_ns >= clock.offset_ns)


def test_tof_rest_statistics_status_and_smoothing():
    sc, const, gt = _setup({"tof.dropout_prob": 0.05}, duration_s=60.0)
    _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(4))
    t = st["tof"]
    valid = t.status == TofStatus.TOF_STATUS_VALID
    assert (~valid).mean() == pytest.approx(0.05, abs=4 * np.sqrt(0.05 * 0.95 / len(t)))
    v = t.values[valid]
    # per-sample SD: white noise (+ the whole-mm rounding and a slow 0.39 mm drift)
    expect = np.sqrt(sc.tof.noise_sd_mm**2 + 1 / 12 + sc.tof.repeat_sd_mm**2)
    assert v.std() == pytest.approx(expect, rel=0.08)
    # the range is the ray-plane model plus the pose-locked error (one pose here)
    assert abs(v.mean() - t.extra["true_mm"][0]) < 4 * sc.tof.pose_sd_mm
    sm, ok = t.extra["smoothed_mm"], t.extra["smoothed_valid"]
    assert ok[20:].mean() > 0.7 and not ok[:5].any()
    assert sm[ok].mean() == pytest.approx(v.mean(), abs=0.3)
    assert sm[ok].std() < 0.6 * v.std()  # a 5-sample average


def test_tof_out_of_range():
    sc, const, gt = _setup({"tof.max_range_mm": 50.0}, duration_s=2.0)
    _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(5))
    t = st["tof"]
    assert np.all(t.status == TofStatus.TOF_STATUS_OUT_OF_RANGE)
    assert np.all(t.values == sc.tof.out_of_range_value_mm)


def test_gyro_bias_walks_faster_in_motion():
    over = {"gyro.bias_rw_static_dps_rts": 0.002, "gyro.bias_rw_motion_dps_rts_per_radps": 0.35}
    sc, const, gt = _setup(over, duration_s=60.0, angle=lambda t: 0.4 * np.sin(2 * np.pi * 0.5 * t))
    _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(6))
    b = st["gyro"].extra["bias_radps"]
    w = np.linalg.norm(st["gyro"].values, axis=1)
    q = np.radians(0.002 + 0.35 * w[1:])
    inc = np.diff(b, axis=0) / np.sqrt(1 / 200)
    np.testing.assert_allclose(np.sqrt(np.mean(inc**2 / q[:, None] ** 2)), 1.0, rtol=0.08)


def test_pose_field_repeatable_and_sized():
    vals = []
    for seed in range(20):
        f = PoseField(np.random.default_rng(seed), 1, 3.04, np.radians(4.0), 0.008)
        R = so3_exp(np.random.default_rng(100 + seed).normal(size=(400, 3)) * 0.5)
        p = np.random.default_rng(200 + seed).normal(size=(400, 3)) * 0.05
        v = f(R, p)[:, 0]
        np.testing.assert_array_equal(v, f(R, p)[:, 0])  # same pose, same error
        vals.append(v.std())
    assert np.sqrt(np.mean(np.square(vals))) == pytest.approx(3.04, rel=0.15)
    # nearby poses are correlated
    f = PoseField(np.random.default_rng(0), 1, 1.0, np.radians(4.0), 0.008)
    R = so3_exp(np.zeros((2, 3)))
    p = np.array([[0.0, 0, 0], [0.0005, 0, 0]])
    assert abs(np.diff(f(R, p)[:, 0])[0]) < 0.3


def test_ou_process_sd():
    x = ou_process(np.random.default_rng(0), np.arange(200_000) * 0.01, 0.39, 2.0)
    assert x.std() == pytest.approx(0.39, rel=0.1)


def test_accel_self_recalibration_jump():
    over = {"accel.self_recal": True, "accel.self_recal_jump_time_s": 10.0, "accel.self_recal_settle_tau_s": 5.0}
    sc, const, gt = _setup(over, duration_s=40.0)
    _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(7))
    a = st["accel"]
    norm = np.linalg.norm(a.values, axis=1) / 9.80665
    t = a.t_true_ns * 1e-9
    assert abs(norm[t < 9.5].mean() - 1.0) < 0.0006  # off: within 0.06 % of g
    assert norm[(t > 10.0) & (t < 10.5)].mean() == pytest.approx(1.063, abs=0.004)
    assert norm[t > 35].mean() == pytest.approx(1.055, abs=0.002)


def test_mag_session_scale_and_pose_disturbance():
    sc, const, gt = _setup(duration_s=5.0)
    scales = []
    for seed in range(6):
        _, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(seed))
        scales.append(st["mag"].extra["session_scale"][0])
        m = st["mag"].values
        assert np.linalg.norm(m.mean(0)) == pytest.approx(scales[-1] * sc.mag.earth_field_ut, rel=0.2)
    assert min(scales) >= sc.mag.session_scale_min and max(scales) <= sc.mag.session_scale_max


def _field_to_gravity_change_deg(st: dict) -> float:
    """How much the angle between the magnetometer's field and the accelerometer's gravity changed
    from the rest before a turn (0.2-1.8 s) to the rest after it (4.2-5.8 s)."""
    angles = []
    for lo, hi in ((0.2, 1.8), (4.2, 5.8)):
        a, m = st["accel"], st["mag"]
        ea = a.values[(a.t_true_ns > lo * 1e9) & (a.t_true_ns < hi * 1e9)].mean(0)
        em = m.values[(m.t_true_ns > lo * 1e9) & (m.t_true_ns < hi * 1e9)].mean(0)
        angles.append(np.degrees(np.arccos(ea @ em / np.linalg.norm(ea) / np.linalg.norm(em))))
    return abs(angles[1] - angles[0])


@pytest.mark.parametrize("hard_iron_ut, paper_is_typical", [(None, True), (1.0, False), (3.0, False)])
def test_mag_hard_iron_sized_to_the_papers_field_to_gravity_change(hard_iron_ut, paper_is_typical):
    """The paper's field-to-gravity angle changed by up to 4.8 deg between poses: over draws of
    the session (hard iron, pose disturbance) one 90 deg turn changes it by less than that in the
    median and by more in the top tenth, at the default size; a third of it (1 uT) puts 4.8 deg
    beyond nearly every draw, 3 uT (the size before) makes it less than a median draw."""
    over = {} if hard_iron_ut is None else {"mag.hard_iron_sd_ut": hard_iron_ut}
    sc, const, gt = _setup(
        over, duration_s=6.0, angle=lambda t: np.pi / 2 * np.clip((t - 2.0) / 2.0, 0, 1), axis=[0, 1, 0]
    )
    changes = [
        _field_to_gravity_change_deg(sensors.simulate_sensors(gt, sc, const, np.random.default_rng(seed))[2])
        for seed in range(40)
    ]
    typical = np.median(changes) < 4.8 < np.percentile(changes, 90)
    assert typical == paper_is_typical, (np.median(changes), np.percentile(changes, 90))
