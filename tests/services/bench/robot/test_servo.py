"""RCM servo: port projection, roll measure, shaft line on the port, joint limits never exceeded."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.robot.fr3 import FR3_DQ_MAX_RADPS, FR3_Q_MAX_RAD, FR3_Q_MIN_RAD, Fr3Kinematics
from services.bench.robot.motion import MotionConfig, neutral_posture, simulate
from services.bench.robot.servo import RcmServo, ServoParams, project_onto_port, roll_about_shaft
from tiplog.geometry import so3_exp

RCM_TOL_M = 0.05e-3


def test_projection_keeps_direction_and_clips_depth() -> None:
    r = np.array([0.5, 0.0, 0.2])
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    L = rng.uniform(0.05, 0.25, 200)
    p_raw = r + L[:, None] * d
    dp_raw = rng.normal(size=(200, 3)) * 0.01
    p_d, dp_d, u_d = project_onto_port(p_raw, dp_raw, r, 0.13, 0.15)
    np.testing.assert_allclose(u_d, d, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(p_d - r, axis=1), np.clip(L, 0.13, 0.15), atol=1e-12)
    inside = (L > 0.13) & (L < 0.15)
    np.testing.assert_allclose(p_d[inside], p_raw[inside], atol=1e-12)
    np.testing.assert_allclose(dp_d[inside], dp_raw[inside], atol=1e-12)
    # Rate of the projected target by finite differences.
    h = 1e-7
    p_d2, _, _ = project_onto_port(p_raw + h * dp_raw, dp_raw, r, 0.13, 0.15)
    np.testing.assert_allclose((p_d2 - p_d) / h, dp_d, atol=1e-6)
    with pytest.raises(ValueError, match="p_raw_m"):
        project_onto_port(r[None], np.zeros((1, 3)), r, 0.13, 0.15)


def test_roll_measure_is_zero_for_pitch_and_exact_for_roll() -> None:
    R0 = MotionConfig().R_neutral()
    u0 = R0[:, 2]
    a = np.cross(u0, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    for ang in (-0.4, 0.1, 0.5):
        assert abs(roll_about_shaft(so3_exp(ang * a) @ R0, R0)) < 1e-12
        R = so3_exp(0.3 * a) @ so3_exp(ang * u0) @ R0
        assert roll_about_shaft(R, R0) == pytest.approx(ang, abs=1e-12)


def _assert_limits(gt) -> None:
    assert np.all(gt.q_rad >= FR3_Q_MIN_RAD) and np.all(gt.q_rad <= FR3_Q_MAX_RAD)
    assert np.all(np.abs(gt.dq_radps) <= FR3_DQ_MAX_RADPS * (1 + 1e-12))


@pytest.mark.slow
@pytest.mark.parametrize(
    "protocol", ["sweep_pitch", "sweep_roll", "sweep_depth", "teleop1", "teleop2", "teleop3", "teleop4"]
)
def test_shaft_line_stays_on_the_port(protocol: str) -> None:
    cfg = MotionConfig()
    gt = simulate(cfg, protocol, seed=7, duration_s=25.0)
    err = gt.rcm_error_m()
    assert err.max() < RCM_TOL_M, f"{protocol}: shaft line {err.max() * 1e3:.4f} mm from the RCM"
    np.testing.assert_allclose(gt.p_tip_base_m, gt.p_target_base_m, atol=0.1e-3)
    # Rates are consistent with the integrated positions (the log is self-consistent).
    np.testing.assert_allclose(np.diff(gt.q_rad, axis=0), gt.dq_radps[:-1] / cfg.rate_hz, atol=1e-12)
    _assert_limits(gt)


@pytest.mark.slow
def test_paper_correction_also_holds_the_port() -> None:
    cfg = MotionConfig(correction="target")
    gt = simulate(cfg, "sweep_pitch", seed=0, duration_s=20.0)
    assert gt.rcm_error_m().max() < RCM_TOL_M
    _assert_limits(gt)


def test_joint_limits_are_never_exceeded_when_commanded_past_them() -> None:
    cfg = MotionConfig()
    kin = Fr3Kinematics(cfg.mount())
    q0 = neutral_posture(cfg, kin)
    R0 = cfg.R_neutral()
    r = np.asarray(cfg.rcm_base_m)
    params = ServoParams(k_roll_per_s=50.0)
    servo = RcmServo(kin, r, R0, q0, params)
    n = 3000
    p = np.repeat((r + 0.14 * R0[:, 2])[None], n, 0)
    # A roll ramp to 200 deg at 200 deg/s drives joint 7 into its limit.
    roll = np.minimum(np.arange(n) / 1000.0 * np.deg2rad(200.0), np.deg2rad(200.0))
    roll = np.where(roll > np.pi, roll - 2 * np.pi, roll)
    log = servo.run(q0, p, np.zeros_like(p), roll, np.gradient(roll) * 1000.0)
    assert np.all(log.q_rad >= FR3_Q_MIN_RAD) and np.all(log.q_rad <= FR3_Q_MAX_RAD)
    assert np.all(np.abs(log.dq_radps) <= FR3_DQ_MAX_RADPS * (1 + 1e-12))
    assert np.abs(log.q_rad[:, 6]).max() > 2.9  # it really went to the limit


def test_tip_speed_is_capped() -> None:
    cfg = MotionConfig()
    kin = Fr3Kinematics(cfg.mount())
    q0 = neutral_posture(cfg, kin)
    r = np.asarray(cfg.rcm_base_m)
    R0 = cfg.R_neutral()
    servo = RcmServo(kin, r, R0, q0, ServoParams())
    n = 1500
    # A 20 mm step in depth: the servo must not exceed 50 mm/s getting there.
    p = np.repeat((r + 0.16 * R0[:, 2])[None], n, 0)
    log = servo.run(q0, p, np.zeros_like(p), np.zeros(n), np.zeros(n))
    speed = np.linalg.norm(np.diff(log.p_tip_base_m, axis=0), axis=1) * 1000.0
    assert speed.max() <= 0.05 * (1 + 1e-3)
    assert np.linalg.norm(log.p_tip_base_m[-1] - p[-1]) < 1e-5
