"""The static-trial filter: heading branch by reprojection, plane and ToF updates, and the
per-trial displacement on a short bench translation session against the bench's truth
(read here, in the test, never by the estimator, which gives the same result bit for bit when
the truth is removed from the file)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from study.static_filter import (
    E_S,
    StaticFilter,
    StaticParams,
    heading_branches,
    inclined_rotation,
    initial_heading,
    reprojection_px,
)
from study.static_trials import _events, estimate_trials, trial_windows
from tiplog import mcap_io
from tiplog.calibration import Calibration
from tiplog.cli import main as tiplog_main
from tiplog.geometry import quat_to_rot, rotation_angle, so3_exp
from tiplog.geometry.vision import closest_axis_point, tangent_plane_normals
from tiplog.mcap_io import McapWriter

pytestmark = pytest.mark.slow  # generates a 30 s bench session

ESTIMATOR_TOPICS = ["device/gyro", "device/accel", "device/tof", "vision/observation", "camera/info"]


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("static") / "translation.mcap"
    args = ["sim", "generate", "--scenario", "translation", "--seed", "11", "--duration", "30", "--out", str(path)]
    assert tiplog_main([*args, "--quiet"]) == 0
    return path


def _truth(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, p, q = [], [], []
    for r in mcap_io.read_messages(path, ["bench/robot"]):
        m = r.message
        t.append(m.header.stamp_ns)
        p.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        o = m.tool_pose.orientation
        q.append((o.x, o.y, o.z, o.w))
    return np.array(t), np.array(p), quat_to_rot(np.array(q))


def _normals(calib: Calibration, R: np.ndarray, depth_m: float) -> np.ndarray:
    """Exact (n_L, n_R) of the shaft at orientation R (camera frame), (1, 2, 3)."""
    A = calib.R_base_camera.T
    tip_c = A @ (calib.rcm_base_m + depth_m * R @ E_S - calib.p_base_camera_m)
    u_c = A @ R @ E_S
    n_l, n_r = tangent_plane_normals(closest_axis_point(tip_c, u_c), u_c, calib.shaft_radius_m)
    return np.stack([n_l, n_r])[None]


def test_heading_branch_chosen_by_reprojection(session):
    md = mcap_io.read_metadata(session)
    calib = Calibration.from_mcap_metadata(md)
    w = trial_windows(md)[0]
    ev = [e for e in _events(session, calib) if w.pre_ns[0] <= e[0] <= w.pre_ns[1]]
    f = np.mean([e[2] for e in ev if e[1] == 1], axis=0)
    normals = np.array([[e[2][0], e[2][1]] for e in ev if e[1] == 3])
    R, scores = initial_heading(calib, f, normals)
    t, _, R_true = _truth(session)
    R_t = R_true[np.searchsorted(t, w.pre_ns[0])]
    assert np.degrees(rotation_angle(R.T @ R_t)) < 1.0
    # the plane constraints alone leave a second branch; reprojection rejects it clearly
    branches = heading_branches(inclined_rotation(f, calib.R_tool_imu), normals, calib.R_base_camera.T)
    assert len(branches) >= 2 and len(scores) >= 2
    assert scores[1] > 5 * scores[0]


def test_plane_update_corrects_heading(session):
    calib = Calibration.from_mcap_metadata(mcap_io.read_metadata(session))
    filt = StaticFilter(calib)
    R_true = inclined_rotation(np.array([0.1, -4.9, -8.4]), calib.R_tool_imu)
    R_true = so3_exp(np.array([0.0, 0.0, 0.3])) @ R_true
    n = _normals(calib, R_true, 0.13)[0]
    # the planes see the shaft leave the plane through the camera and the axis (normal w)
    u = R_true @ E_S
    w = calib.R_base_camera @ (n[0] - n[1])
    axis = np.cross(u, w) / np.linalg.norm(np.cross(u, w))
    s = filt.new_state(0, so3_exp(np.radians(2.0) * axis) @ R_true, 0.13)
    before = rotation_angle(s.R.T @ R_true)
    for _ in range(20):
        filt.update_vision(s, n[0], n[1], None)
    assert s.counts.get("updates:vision_planes") == 20
    assert rotation_angle(s.R.T @ R_true) < 0.2 * before
    assert reprojection_px(calib, R_true, n[None]) < 1e-6


def test_tof_depth_inverse(session):
    calib = Calibration.from_mcap_metadata(mcap_io.read_metadata(session))
    filt = StaticFilter(calib)
    R = inclined_rotation(np.array([0.1, -4.9, -8.4]), calib.R_tool_imu)
    rho = filt.tof_range(R, 0.137)
    assert filt.depth_from_tof(R, rho) == pytest.approx(0.137, abs=1e-9)
    assert filt.tof_range(R, 0.147) != pytest.approx(rho, abs=1e-3)  # the range sees depth


def test_trial_displacements_against_truth(session):
    est, counts = estimate_trials(session)
    assert len(est) >= 2 and counts.get("updates:vision_planes", 0) > 50
    t, p, _ = _truth(session)
    for e in est:
        w = e.windows
        tail = [(t >= hi - (hi - lo) // 2) & (t <= hi) for lo, hi in (w.pre_ns, w.post_ns)]
        d_true = p[tail[1]].mean(0) - p[tail[0]].mean(0)
        assert np.linalg.norm(d_true) * 1e3 == pytest.approx(abs(w.magnitude), abs=0.5)  # the trial is what it says
        assert np.linalg.norm(e.displacement_base_m - d_true) * 1e3 < 2.0


def test_estimate_identical_without_truth(session, tmp_path):
    """Bit for bit the same when the file holds no truth (no bench topics, no
    calibration_truth, no poses in the trials)."""
    md = mcap_io.read_metadata(session)
    blind = tmp_path / "blind.mcap"
    trials = json.loads(md["trials"]["json"])
    keep = ("index", "kind", "axis", "magnitude", "unit", "pre_start", "pre_end", "post_start", "post_end")
    with McapWriter(blind) as w:
        for r in mcap_io.read_messages(session, ESTIMATOR_TOPICS):
            w.write(r.topic, r.message, r.log_time_ns)
        w.add_metadata("calibration_as_calibrated", md["calibration_as_calibrated"])
        w.add_metadata("trials", {"json": json.dumps([{k: tr.get(k) for k in keep} for tr in trials])})
    a, _ = estimate_trials(session)
    b, _ = estimate_trials(blind)
    assert len(a) == len(b) > 0
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.displacement_base_m, y.displacement_base_m)
        np.testing.assert_array_equal(x.R_rel, y.R_rel)


def test_ablation_names_are_checked(tmp_path):
    with pytest.raises(ValueError, match="magnetometer"):
        estimate_trials(tmp_path / "unused.mcap", updates=frozenset({"accel", "magnetometer"}))


def test_the_translation_protocol_keeps_the_calibrations_mounting(session):
    """The mounting is learnt in the rotation protocol only: by default a translation session is
    run with the mounting held, and learning it would change the estimate."""
    held, _ = estimate_trials(session, params=StaticParams(init_mount_deg=0.0))
    default, _ = estimate_trials(session)
    learnt, _ = estimate_trials(session, params=StaticParams(init_mount_deg=0.3))
    for a, b in zip(held, default, strict=True):
        np.testing.assert_array_equal(a.displacement_base_m, b.displacement_base_m)
    assert any(
        not np.array_equal(a.displacement_base_m, c.displacement_base_m) for a, c in zip(held, learnt, strict=True)
    )
