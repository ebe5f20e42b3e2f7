"""The pure fits on synthetic data with known constants, and their refusals of data that
cannot determine them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tiplog.calibration.fits import DegenerateDataError
from tiplog.calibration.fits.camera import CameraFrames, fit_camera
from tiplog.calibration.fits.imu import G_MPS2, fit_accel, fit_mount_accel, fit_mount_gyro, rotation_error_deg
from tiplog.calibration.fits.rcm import fit_rcm
from tiplog.calibration.fits.tof import TofModel, fit_tof
from tiplog.calibration.fits.vision_offset import fit_vision_offset
from tiplog.geometry import so3_exp, so3_log
from tiplog.geometry import vision as vg


def _poses(rng, k, tilt_deg=8.0, roll_deg=40.0):
    """k rotations about a neutral shaft 30 deg from vertical, tip 140 mm past an RCM."""
    R0 = so3_exp(np.array([0.0, np.radians(150.0), 0.0]))
    R = np.stack(
        [
            R0
            @ so3_exp(np.radians([rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-tilt_deg, tilt_deg), 0.0]))
            @ so3_exp(np.array([0.0, 0.0, np.radians(rng.uniform(-roll_deg, roll_deg))]))
            for _ in range(k)
        ]
    )
    rcm = np.array([0.65, 0.0, 0.3])
    return R, rcm + 0.14 * R[:, :, 2], rcm


def test_rcm_recovers_the_crossing_point_and_refuses_parallel_lines():
    rng = np.random.default_rng(0)
    R, p, rcm = _poses(rng, 10)
    res = fit_rcm(p + rng.normal(size=p.shape) * 1e-5, R)
    assert np.linalg.norm(res.rcm_base_m - rcm) < 1e-4
    R_par = np.repeat(R[:1], 5, 0)
    with pytest.raises(DegenerateDataError, match="do not cross"):
        fit_rcm(p[:1] + np.arange(5)[:, None] * 1e-3 * R[0, :, 2], R_par)
    with pytest.raises(DegenerateDataError, match="do not cross"):  # one pose held: exactly singular
        fit_rcm(np.repeat(p[:1], 5, 0), R_par)
    with pytest.raises(DegenerateDataError, match="at least 3"):
        fit_rcm(p[:2], R[:2])


def test_gyro_mounting_recovers_a_known_rotation_and_refuses_one_axis_motion():
    rng = np.random.default_rng(1)
    R_ti = so3_exp(np.radians([1.5, -2.0, 91.0]))
    w_tool = rng.normal(size=(2000, 3)) * 0.5
    w_imu = w_tool @ R_ti + rng.normal(size=w_tool.shape) * 0.002
    res = fit_mount_gyro(w_imu, w_tool)
    assert rotation_error_deg(res.R_tool_imu, R_ti) < 0.05
    one_axis = np.outer(rng.normal(size=2000), [0.0, 0.0, 1.0])
    with pytest.raises(DegenerateDataError, match="one axis"):
        fit_mount_gyro(one_axis @ R_ti, one_axis)


def test_accel_recovers_bias_scale_misalignment_on_diverse_poses():
    rng = np.random.default_rng(2)
    R = so3_exp(rng.normal(size=(40, 3)) * 1.5)  # poses all round the sphere
    R_ti = so3_exp(np.radians([1.0, 2.0, -3.0]))
    E = np.array([[0.01, 0.002, -0.001], [0.002, -0.015, 0.003], [-0.001, 0.003, 0.005]])
    b = np.array([0.05, -0.03, 0.08])
    f = np.einsum("kji,j->ki", R, [0, 0, G_MPS2]) @ R_ti
    a = f @ (np.eye(3) + E).T + b + rng.normal(size=f.shape) * 0.002
    res = fit_accel(a, R, R_ti, pose_sd_deg=0.01)
    assert np.allclose(res.bias_mps2, b, atol=0.005)
    assert np.allclose(res.scale, 1.0 + np.diag(E), atol=0.001)
    assert np.allclose(res.misalignment, [E[0, 1], E[0, 2], E[1, 2]], atol=0.001)
    assert res.heldout_deg < 0.05
    m = fit_mount_accel(a, R)
    assert rotation_error_deg(m.R_tool_imu, R_ti) < 1.0  # scale/bias left in: coarse only


def test_accel_refuses_too_few_poses_and_a_single_attitude():
    rng = np.random.default_rng(3)
    R, _, _ = _poses(rng, 6)
    f = np.einsum("kji,j->ki", R, [0, 0, G_MPS2])
    with pytest.raises(DegenerateDataError, match="at least 4"):
        fit_accel(f[:3], R[:3], np.eye(3))
    same = np.repeat(R[:1], 6, 0)
    with pytest.raises(DegenerateDataError, match="varies by only"):
        fit_accel(np.repeat(f[:1], 6, 0), same, np.eye(3))


def test_tof_recovers_the_range_model_from_many_poses_and_refuses_too_few():
    rng = np.random.default_rng(4)
    R, p, rcm = _poses(rng, 40, tilt_deg=12.0, roll_deg=60.0)
    m = R[0, :, 2] * 0 + np.array([0.64, -0.12, -0.76])
    m /= np.linalg.norm(m)
    b = np.array([0.0, np.sin(np.radians(55.8)), np.cos(np.radians(55.8))])
    truth = TofModel(np.array([0.0, 0.015, -0.284]), b, m, float(m @ rcm))
    rho = truth.range_m(R, p) * 1e3 + rng.normal(size=len(R)) * 0.3
    start = TofModel(
        truth.origin_tool_m + [0.001, -0.001, 0.002],
        so3_exp(np.radians([0.5, 0.0, 0.0])) @ b,
        so3_exp(np.radians([0.0, 0.5, 0.0])) @ m,
        truth.plane_h_m + 0.001,
    )
    res = fit_tof(rho, np.full(len(R), 3.0), np.full(len(R), 300), R, p, start, pose_sd_mm=0.3)
    err = res.model.range_m(R, p) - truth.range_m(R, p)
    assert np.sqrt(np.mean(err**2)) * 1e3 < 0.2
    assert res.heldout_mm < 0.6 < res.prior_heldout_mm
    with pytest.raises(DegenerateDataError, match="at least 9"):
        fit_tof(rho[:8], np.ones(8), np.ones(8), R[:8], p[:8], start)


def test_vision_offset_mean_of_pose_medians_and_refusal():
    rng = np.random.default_rng(5)
    per_pose = [-0.0005 + rng.normal(size=30) * 3e-4 for _ in range(10)]
    res = fit_vision_offset(per_pose)
    assert abs(res.vision_tip_offset_m + 0.0005) < 2e-4
    with pytest.raises(DegenerateDataError, match="at least 3"):
        fit_vision_offset(per_pose[:2] + [np.array([np.nan] * 5)])


def _camera_frames(rng, k=10, per_pose=20, L_j=0.004, rho=0.0025, wrong=0):
    """Exact silhouettes and junction rays of k static poses seen by a camera 250 mm from the
    tip; `wrong` frames get a wrong line (one normal tilted 4 deg)."""
    R, p, _ = _poses(rng, k)
    target = p.mean(0)
    c = target + np.array([0.05, -0.24, 0.05])
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.stack([x, np.cross(z, x), z], 1), c
    R, p = np.repeat(R, per_pose, 0), np.repeat(p, per_pose, 0)
    A = T[:3, :3].T
    u_c, p_c = R[:, :, 2] @ A.T, (p - c) @ A.T
    n_l, n_r = vg.tangent_plane_normals(vg.closest_axis_point(p_c, u_c), u_c, rho)
    ray = (p - L_j * R[:, :, 2] - c) @ A.T
    for i in rng.choice(len(p), wrong, replace=False):
        n_l[i] = so3_exp(np.radians(4.0) * u_c[i]) @ n_l[i]
    frames = CameraFrames(
        pose=np.repeat(np.arange(k), per_pose),
        R_base_tool=R,
        p_tip_base_m=p,
        n_left=n_l,
        n_right=n_r,
        junction_ray=ray / np.linalg.norm(ray, axis=1, keepdims=True),
        junction_visible=np.ones(len(p), bool),
    )
    return frames, T


def test_camera_pose_and_junction_distance_recovered_from_a_perturbed_start_despite_wrong_lines():
    rng = np.random.default_rng(4)
    frames, T = _camera_frames(rng, wrong=15)
    start = T.copy()
    start[:3, :3] = so3_exp(np.radians([0.4, -0.3, 0.2])) @ T[:3, :3]
    start[:3, 3] += [1.5e-3, -1.0e-3, 0.8e-3]
    res = fit_camera(frames, start, 0.0055, 0.0025)
    assert np.degrees(np.linalg.norm(so3_log(res.T_base_camera[:3, :3] @ T[:3, :3].T))) < 0.01
    assert np.linalg.norm(res.T_base_camera[:3, 3] - T[:3, 3]) < 2e-5
    assert abs(res.junction_proximal_m - 0.004) < 2e-5
    assert res.rotation_change_deg > 0.5 and res.position_change_mm > 1.5
    assert res.residual_mm["planes"] < 1e-3 and res.heldout_mm["junction"] < 1e-3
    assert res.dropped >= 15 and res.poses == 10  # the wrong lines are dropped, not fitted


def test_camera_fit_refuses_too_few_poses_parallel_shafts_and_no_junction():
    rng = np.random.default_rng(5)
    frames, T = _camera_frames(rng, k=10, per_pose=9)

    def only(keep):
        return CameraFrames(*(getattr(frames, f)[keep] for f in CameraFrames.__dataclass_fields__))

    with pytest.raises(DegenerateDataError, match="at least 3 static poses"):
        fit_camera(only(frames.pose < 2), T, 0.004, 0.0025)
    one_pose = only(frames.pose == 0)
    with pytest.raises(DegenerateDataError, match="span only"):  # one direction, called three poses
        fit_camera(dataclasses.replace(one_pose, pose=np.arange(9) % 3), T, 0.004, 0.0025)
    with pytest.raises(DegenerateDataError, match="junction"):
        fit_camera(dataclasses.replace(frames, junction_visible=np.zeros(90, bool)), T, 0.004, 0.0025)
