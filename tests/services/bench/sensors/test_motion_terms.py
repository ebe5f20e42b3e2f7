"""Device motion terms: ToF ranging time and footprint, per-session correlation lengths,
accelerometer vibration and mount compliance."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.scenario import load_scenario
from services.bench.sensors import device as sensors
from services.bench.sensors import motion_terms as mt
from services.bench.sensors.calibration import true_constants
from tests.services.bench.synthetic_truth import pivot

# the clean profile with the device's other error terms off: each test switches on one term
QUIET = {
    "profile": "clean",
    "tof.noise_sd_mm": 0.0,
    "tof.pose_sd_mm": 0.0,
    "tof.repeat_sd_mm": 0.0,
    "tof.dropout_prob": 0.0,
    "accel.noise_sd_mps2": 0.0,
    "accel.pose_tilt_sd_deg": 0.0,
    "accel.bias_sd_mps2": 0.0,
    "accel.scale_sd": 0.0,
}


def _streams(overrides, angle, duration_s=10.0, seed=0, axis=(1.0, 0.0, 0.0)):
    sc = load_scenario("static", {**QUIET, **overrides})
    const = true_constants(sc)
    gt = pivot(sc.motion.R_neutral(), const.rcm_base_m, 0.14, duration_s, np.array(axis), angle)
    kin, _, st = sensors.simulate_sensors(gt, sc, const, np.random.default_rng(seed))
    rho = const.tof_range_m(
        sensors._interp_R(st["tof"].t_true_ns, kin.t_ns, kin.R_base_tool),
        sensors._interp(st["tof"].t_true_ns, kin.t_ns, kin.p_tip_base_m),
    )
    return sc, kin, st, rho * 1e3


def test_ranging_time_averages_without_delay():
    fast = lambda t: 0.1 * np.sin(2 * np.pi * 6.0 * t)  # noqa: E731
    _, _, inst, rho = _streams({"tof.integration_ms": 0.0}, fast)
    _, _, integ, _ = _streams({"tof.integration_ms": 40.0}, fast)
    a0 = inst["tof"].extra["true_mm"] - inst["tof"].extra["true_mm"].mean()
    a1 = integ["tof"].extra["true_mm"] - integ["tof"].extra["true_mm"].mean()
    np.testing.assert_allclose(inst["tof"].extra["true_mm"], rho)
    # the mean over the ranging time's sub-samples keeps mean(cos(2 pi f o)) of a swing at f,
    # centred on the sample instant: no lag
    keep = np.mean(np.cos(2 * np.pi * 6.0 * mt.integration_offsets_ns(40.0) * 1e-9))
    assert 0.8 < keep < 0.95
    assert np.std(a1) / np.std(a0) == pytest.approx(keep, rel=0.05)
    assert abs(np.corrcoef(a0, a1)[0, 1]) > 0.99


def test_surface_relief_is_averaged_over_the_footprint():
    rng = np.random.default_rng(0)
    relief = mt.SurfaceRelief(rng, 1e-3, 0.01)
    xy = rng.uniform(-0.2, 0.2, (4000, 2))
    point = relief(xy, np.zeros(len(xy)))
    wide = relief(xy, np.full(len(xy), 0.02))
    assert np.std(point) == pytest.approx(1e-3, rel=0.3)
    # a Gaussian footprint of SD s over a squared-exponential relief of length l keeps
    # 1 / sqrt(1 + 2 (s / l)^2) of its SD: a third at s = 2 l
    assert np.std(wide) / np.std(point) == pytest.approx(1.0 / 3.0, rel=0.3)


def test_relief_changes_the_range_in_motion_only_by_its_size():
    swing = lambda t: 0.1 * np.sin(2 * np.pi * 0.3 * t)  # noqa: E731
    _, _, st, rho = _streams({"tof.surface_relief_mm": 1.0, "tof.surface_corr_mm": 15.0}, swing, 30.0)
    err = st["tof"].extra["true_mm"] - rho
    assert 0.05 < np.std(err) < 3.0
    _, _, flat, _ = _streams({}, swing, 30.0)
    np.testing.assert_allclose(flat["tof"].extra["true_mm"], rho)


def test_correlation_lengths_vary_between_sessions():
    lens = {
        tuple(_streams({"tof.pose_corr_spread": 2.0}, None, 1.0, seed)[2]["tof"].extra["pose_corr"])
        for seed in range(4)
    }
    assert len(lens) == 4
    for deg, m in lens:
        assert 2.0 <= deg <= 8.0 and 0.004 <= m <= 0.016
    same = _streams({}, None, 1.0, 5)[2]["tof"].extra["pose_corr"]
    np.testing.assert_allclose(same, [4.0, 0.008])


def test_vibration_grows_with_speed_and_compliance_follows_acceleration():
    swing = lambda t: 0.1 * np.sin(2 * np.pi * 0.5 * t)  # noqa: E731
    _, kin, st, _ = _streams({"accel.vibration_mps2_per_mps": 2.0}, swing)
    vib = st["accel"].extra["vibration_mps2"]
    dt = 1e-3
    v = np.interp(st["accel"].t_true_ns, kin.t_ns, np.linalg.norm(np.gradient(kin.p_tip_base_m, dt, axis=0), axis=1))
    fast, slow = v > np.percentile(v, 70), v < np.percentile(v, 30)
    assert np.sqrt(np.mean(vib[fast] ** 2)) > 3 * np.sqrt(np.mean(vib[slow] ** 2))
    assert np.sqrt(np.mean(vib**2)) == pytest.approx(2.0 * np.sqrt(np.mean(v**2)), rel=0.25)
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    tilt = mt.compliance_tilt(a, np.array([0.0, 0.0, 1.0]), 0.05)
    np.testing.assert_allclose(tilt[0], 0.0)
    assert np.degrees(np.linalg.norm(tilt[1])) == pytest.approx(0.05)
