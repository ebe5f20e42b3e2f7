"""The static-trial filter learns the IMU's mounting error across the shaft from the tool's
turns: synthetic rolls about the shaft with a gyro and an accelerometer mounted 0.5 deg off the
calibration's mounting, and vision frames from the calibration's own geometry. Learning it
must take at least half the mounting error out, and leave the attitude after the turns less than
half as far from the truth as the calibration's mounting taken as exact does. (The accelerometer
does not update the mounting directly, so the learning is slow; on the bench that keeps its
pose-locked errors out of it.)"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from study.static_filter import E_S, StaticFilter, StaticParams
from study.static_trials import estimate_trials
from tests.services.fusion.sessions import bench_geometry, bench_session
from tiplog.calibration import Calibration
from tiplog.geometry import rotation_angle, so3_exp, so3_log
from tiplog.geometry.vision import closest_axis_point, tangent_plane_normals
from tiplog.mcap_io import read_metadata

G_MPS2 = 9.81
MOUNT_ERROR = np.radians([0.5, -0.4, 0.0])  # tool axes: across the shaft


@pytest.fixture(scope="module")
def geometry(tmp_path_factory):
    return bench_geometry(tmp_path_factory)


def _normals(calib: Calibration, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    A = calib.R_base_camera.T
    rcm_cam = A @ (calib.rcm_base_m - calib.p_base_camera_m)
    u_cam = A @ R @ E_S
    return tangent_plane_normals(closest_axis_point(rcm_cam, u_cam), u_cam, calib.shaft_radius_m)


def _rolls(calib: Calibration, R0: np.ndarray, init_mount_deg: float) -> tuple[StaticFilter, object, np.ndarray]:
    """Hold 2 s, roll 90 deg about the shaft in 3 s, hold, roll back, four times; the filter
    starts at the true attitude. Returns the filter, its state and the true final attitude."""
    M_true = so3_exp(MOUNT_ERROR) @ calib.R_tool_imu
    f = StaticFilter(calib, StaticParams(init_mount_deg=init_mount_deg))
    s = f.new_state(0, R0, 0.13)
    rate = math.radians(30.0)
    phases = [(2.0, 0.0), (3.0, rate), (2.0, 0.0), (3.0, -rate)] * 4 + [(2.0, 0.0)]
    R, t_ns = R0.copy(), 0
    for duration, w in phases:
        w_tool = w * E_S
        for k in range(int(duration * 600)):  # a 600 Hz clock: gyro every 3rd, accel every 2.5th, camera every 20th
            t_ns += 1_666_667
            R = R @ so3_exp(w_tool / 600.0)
            if k % 3 == 0:
                f.on_gyro(s, t_ns, M_true.T @ w_tool)
            if k % 5 in (0, 2):
                f.propagate(s, t_ns)
                f.update_accel(s, M_true.T @ R.T @ np.array([0.0, 0.0, G_MPS2]))
            if k % 20 == 0:
                f.propagate(s, t_ns)
                f.update_vision(s, *_normals(calib, R), None)
    return f, s, R


def test_the_mounting_across_the_shaft_is_learnt_from_the_turns(geometry):
    calib, R0 = geometry
    f, s, R_true = _rolls(calib, R0, init_mount_deg=0.3)
    learnt = so3_log(f.R_tool_imu(s) @ calib.R_tool_imu.T)
    assert np.linalg.norm(learnt[:2] - MOUNT_ERROR[:2]) < 0.5 * np.linalg.norm(MOUNT_ERROR)
    assert abs(learnt[2]) < 1e-9  # along the shaft: not observable, left to the calibration
    assert s.counts.get("updates:vision_planes", 0) > 500 and s.counts.get("updates:accel", 0) > 4000
    held, t, _ = _rolls(calib, R0, init_mount_deg=0.0)
    np.testing.assert_array_equal(held.R_tool_imu(t), calib.R_tool_imu)
    assert rotation_angle(t.R.T @ R_true) > math.radians(0.5)  # the mounting error, uncorrected
    assert rotation_angle(s.R.T @ R_true) < 0.5 * rotation_angle(t.R.T @ R_true)


@pytest.fixture(scope="module")
def rotation_session(tmp_path_factory):
    return bench_session(tmp_path_factory, "rotation", seed=43, duration_s=40.0)


def test_the_mounting_is_learnt_only_where_the_calibration_does_not_state_it(rotation_session):
    """By default a rotation session learns the mounting from a calibration that does not say how
    well it knows it (the bench's as-calibrated constants) and holds it from one that does (a
    `tiplog calibrate` file)."""
    unstated = Calibration.from_mcap_metadata(read_metadata(rotation_session))
    assert unstated.R_tool_imu_sd_deg is None
    stated = replace(unstated, R_tool_imu_sd_deg=0.09)

    def rel(calib, params=None):
        est, _ = estimate_trials(rotation_session, calib, params)
        assert len(est) >= 2
        return np.array([e.R_rel for e in est])

    learnt, held = rel(unstated, StaticParams()), rel(unstated, StaticParams(init_mount_deg=0.0))
    assert not np.array_equal(learnt, held)
    np.testing.assert_array_equal(rel(unstated), learnt)
    np.testing.assert_array_equal(rel(stated), held)
