"""Measurement-tier vision against the true geometry and the error sizes of the scenario."""

from __future__ import annotations

from math import erf

import numpy as np
import pytest

from services.bench.scenario import load_scenario
from services.bench.sensors import device as sensors
from services.bench.sensors.calibration import true_constants
from services.bench.sensors.vision_model import simulate_vision
from tests.services.bench.synthetic_truth import pivot
from tiplog.geometry import vision as vg

# Noise-free geometry: the clean profile, since every motion source of the others is an error.
EXACT = {
    "profile": "clean",
    "vision.plane_white_deg": 0.0,
    "vision.plane_pose_deg": 0.0,
    "vision.junction_depth_white_mm": 0.0,
    "vision.junction_depth_pose_mm": 0.0,
    "vision.junction_lateral_px": 0.0,
    "vision.wrong_seg_prob": 0.0,
    "vision.junction_hidden_prob": 0.0,
}


def _run(overrides, duration_s=20.0, angle=None, seed=0):
    sc = load_scenario("teleop", overrides)
    const = true_constants(sc)
    gt = pivot(sc.motion.R_neutral(), const.rcm_base_m, 0.14, duration_s, np.array([0.3, 1.0, 0.0]), angle)
    kin = sensors.kinematics(gt, const)
    vf = simulate_vision(kin, sc, const, np.random.default_rng(seed))
    return sc, const, kin, vf


def _truth_cam(const, kin, t_ns):
    R = sensors._interp_R(t_ns, kin.t_ns, kin.R_base_tool)
    p = sensors._interp(t_ns, kin.t_ns, kin.p_tip_base_m)
    A = const.T_base_camera[:3, :3].T
    c = const.T_base_camera[:3, 3]
    return R[:, :, 2] @ A.T, (p - c) @ A.T, A


def test_noise_free_observation_is_the_geometry():
    sc, const, kin, vf = _run(EXACT, angle=lambda t: 0.05 * np.sin(t))
    u, tip, A = _truth_cam(const, kin, vf.t_true_ns)
    ok = np.linalg.norm(vf.n_left, axis=1) > 0
    assert ok.mean() > 0.95
    np.testing.assert_allclose((vf.n_left * u).sum(1)[ok], 0.0, atol=1e-9)  # n^T A u = 0
    np.testing.assert_allclose((vf.n_right * u).sum(1)[ok], 0.0, atol=1e-9)
    p0 = vg.closest_axis_point(tip, u)
    np.testing.assert_allclose(vf.axis_point_m[ok], p0[ok], atol=1e-9)
    # planes about 3.6 deg apart at this camera distance
    apart = 180 - np.degrees(np.arccos((vf.n_left * vf.n_right).sum(1)[ok]))
    assert 2.5 < np.median(apart) < 5.0
    # junction ray meets the axis junction_proximal_m behind the tip
    j = vf.junction_visible
    assert j.mean() > 0.9
    s, _, cond = vg.ray_axis_intersection(vf.junction_ray[j], p0[j], u[j])
    s_tip = ((tip - p0) * u).sum(1)[j]
    np.testing.assert_allclose(s_tip - s, sc.instrument.junction_proximal_m, atol=1e-9)
    assert np.all(cond >= sc.vision.junction_min_sin2)


def test_tangent_plane_and_junction_residuals_match_the_scenario():
    sc, const, kin, vf = _run({"vision.wrong_seg_prob": 0.0}, duration_s=120.0, angle=lambda t: 0.15 * np.sin(0.3 * t))
    u, tip, _ = _truth_cam(const, kin, vf.t_true_ns)
    a = vf.accepted
    res = np.degrees(np.arcsin(np.concatenate([(vf.n_left * u).sum(1)[a], (vf.n_right * u).sum(1)[a]])))
    expect = np.hypot(sc.vision.plane_white_deg, sc.vision.plane_pose_deg)
    assert np.sqrt(np.mean(res**2)) == pytest.approx(expect, rel=0.3)  # pose-locked part: few independent poses
    j = a & vf.junction_visible
    p0 = vg.closest_axis_point(tip, u)
    s, _, _ = vg.ray_axis_intersection(vf.junction_ray[j], p0[j], u[j])
    err_mm = (((tip - p0) * u).sum(1)[j] - s) * 1e3 - sc.instrument.junction_proximal_m * 1e3
    expect = np.hypot(sc.vision.junction_depth_white_mm, sc.vision.junction_depth_pose_mm)
    assert np.sqrt(np.mean(err_mm**2)) == pytest.approx(expect, rel=0.4)


def test_acceptance_falls_with_image_motion_and_gate_measures_are_consistent():
    # the clean gate: independent draws whose spread grows with image speed (the closed form below)
    sc, _, _, rest = _run({"profile": "clean", "vision.wrong_seg_prob": 0.0}, duration_s=120.0)
    _, _, _, moving = _run({"profile": "clean"}, duration_s=60.0, angle=lambda t: 0.12 * np.sin(2 * np.pi * 0.5 * t))
    # at rest each of the four measures passes with P = erf(1 / (s sqrt 2)), s = metric_scale_rest
    p = erf(1.0 / (sc.vision.metric_scale_rest * np.sqrt(2.0))) ** 4
    assert rest.accepted.mean() == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / len(rest)))
    assert 0.55 < moving.accepted.mean() < rest.accepted.mean()
    for vf in (rest, moving):
        gate_ok = (vf.mask_iou >= 0.75) & (vf.line_angle_deg < 0.5) & (vf.lateral_px < 1.5) & (vf.junction_diff_px < 4)
        np.testing.assert_array_equal(vf.accepted, gate_ok)  # every frame is visible here
        assert all((r == "") == a for r, a in zip(vf.reject_reason, vf.accepted, strict=True))


def test_wrong_segmentations_pass_the_gate_but_miss_the_trocar():
    sc, const, kin, vf = _run(
        {"vision.wrong_seg_prob": 0.3, "vision.plane_white_deg": 0.0, "vision.plane_pose_deg": 0.0}
    )
    A = const.T_base_camera[:3, :3].T
    rcm_c = (const.rcm_base_m - const.T_base_camera[:3, 3]) @ A.T
    dist, ok = vg.trocar_gate(vf.n_left, vf.n_right, const.shaft_radius_m, rcm_c)
    w = vf.wrong_segmentation
    assert vf.accepted[w].mean() > 0.8
    assert ok[~w].mean() > 0.99  # exact lines pass through the port
    assert ok[w].mean() < 0.05


def test_stamps_and_processing_time():
    sc, const, kin, vf = _run({}, duration_s=20.0)
    assert len(vf) == pytest.approx(20 * 15, abs=2)
    lat = (vf.capture_ns - vf.t_true_ns) * 1e-6
    assert lat.mean() == pytest.approx(sc.camera.latency_ms, abs=0.2)
    assert np.mean(vf.processing_ms) == pytest.approx(113.0, abs=3.0)
    assert np.all(vf.processed_ns > vf.capture_ns)


def test_gross_junction_errors_follow_the_scenario():
    """The rare gross junction depth errors (labeler and network agreeing on a wrong end) come
    at the scenario's rate and within its size range; everything else stays exact."""
    over = EXACT | {
        "vision.wrong_seg_prob": 1e-12,  # error model on, no wrong lines in practice
        "vision.junction_outlier_prob": 0.2,
        "vision.junction_outlier_mm": (10.0, 12.0),
    }
    sc, const, kin, vf = _run(over, angle=lambda t: 0.05 * np.sin(t))
    u, tip, _ = _truth_cam(const, kin, vf.t_true_ns)
    j = vf.junction_visible & (np.linalg.norm(vf.n_left, axis=1) > 0)
    p0 = vg.closest_axis_point(tip, u)
    s, _, _ = vg.ray_axis_intersection(vf.junction_ray[j], p0[j], u[j])
    err_mm = np.abs((((tip - p0) * u).sum(1)[j] - s) * 1e3 - sc.instrument.junction_proximal_m * 1e3)
    gross = err_mm > 1e-6
    assert gross.mean() == pytest.approx(0.2, abs=0.05), gross.mean()
    assert np.all((err_mm[gross] > 10.0 - 1e-6) & (err_mm[gross] < 12.0 + 1e-6))
    _, _, _, vf0 = _run(over | {"vision.junction_outlier_prob": 0.0}, angle=lambda t: 0.05 * np.sin(t))
    np.testing.assert_array_equal(vf0.junction_visible, vf.junction_visible)  # other draws unchanged
