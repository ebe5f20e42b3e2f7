"""Every fit of the fit-only block on one recording, and the calibration they make.

Starts from the prior constants (a calibration file or the recording's as-calibrated
metadata), replaces what the block determines (RCM, IMU mounting, ToF ray-plane model,
the camera's pose in the base refined on the shaft it sees, vision tip offset, written into
junction_proximal_m; accelerometer bias/scale/misalignment go
to the report, the calibration format has no field for them yet) and returns the new `Calibration` with a report of every
fit's residuals, held-out residuals and posterior SDs.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from tiplog.calibration import Calibration
from tiplog.calibration.data import CalibrationData
from tiplog.calibration.fits import DegenerateDataError, require
from tiplog.calibration.fits.camera import CameraFrames, fit_camera
from tiplog.calibration.fits.imu import combine_mounts, fit_accel, fit_mount_accel, fit_mount_gyro, rotation_error_deg
from tiplog.calibration.fits.rcm import fit_rcm
from tiplog.calibration.fits.tof import TofModel, fit_tof
from tiplog.calibration.fits.vision_offset import fit_vision_offset, junction_offsets_m
from tiplog.calibration.fits.windows import StaticWindows, interp_pose, static_windows, window_samples
from tiplog.geometry import so3_log

log = logging.getLogger(__name__)
BLOCK_FITS = ("rcm", "mounting", "accel", "tof", "camera", "vision_offset")


def _r(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd))


def robot_body_rate(t_ns: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body rate in the tool frame [rad/s] at the midpoints between robot samples."""
    dt = np.diff(t_ns) * 1e-9
    w = so3_log(np.einsum("nji,njk->nik", R[:-1], R[1:])) / dt[:, None]
    return (t_ns[:-1] + t_ns[1:]) // 2, w


def mounting(data: CalibrationData, win: StaticWindows, prior: Calibration, report: dict[str, Any]) -> np.ndarray:
    lat = prior.latency_ms.get("gyro", 0.0)
    gi = window_samples(win, data.gyro_t_ns, lat)
    gi = [i for i in gi if len(i) > 0]
    require(len(gi) > 0, "imu mounting (gyro)", "no gyro samples inside the static poses")
    # the bias moves during motion: interpolate it between the rests on either side of a move
    t_rest = np.array([data.gyro_t_ns[i].mean() for i in gi])
    b_rest = np.array([data.gyro_radps[i].mean(0) for i in gi])
    tm, w_tool = robot_body_rate(data.robot_t_ns, data.R_base_tool)
    tq = data.gyro_t_ns - int(round(lat * 1e6))
    inside = (tq > tm[0]) & (tq < tm[-1])
    w_q = np.stack([np.interp(tq[inside], tm, w_tool[:, j]) for j in range(3)], 1)
    moving = np.linalg.norm(w_q, axis=1) > np.radians(2.0)
    tg = data.gyro_t_ns[inside][moving]
    bias = np.stack([np.interp(tg, t_rest, b_rest[:, j]) for j in range(3)], 1)
    ai = window_samples(win, data.accel_t_ns, prior.latency_ms.get("accel", 0.0))
    keep = [k for k, i in enumerate(ai) if len(i) > 0]
    ma = fit_mount_accel(np.array([data.accel_mps2[ai[k]].mean(0) for k in keep]), win.R_base_tool[keep])
    try:
        mg = fit_mount_gyro(data.gyro_radps[inside][moving], w_q[moving], bias)
        m = combine_mounts(mg, ma)
        between = rotation_error_deg(mg.R_tool_imu, ma.R_tool_imu)
        report["mounting_parts"] = {
            "gyro_sd_deg": _r(mg.jackknife_sd_deg),
            "accel_sd_deg": _r(ma.jackknife_sd_deg),
            "gyro_to_accel_deg": _r(between),
        }
    except DegenerateDataError as e:
        log.warning("%s; mounting from the accelerometer's gravity directions alone", e)
        m = ma
    report["mounting"] = {
        "source": m.source,
        "sd_deg": _r(m.jackknife_sd_deg),
        "residual_dps": _r(m.residual_dps),
        "heldout_dps": _r(m.heldout_dps),
        "samples": m.samples,
        "gyro_bias_at_rest_dps": [_r(x, 5) for x in np.degrees(np.median(b_rest, 0))],
    }
    return m.R_tool_imu


def camera_frames(data: CalibrationData, win: StaticWindows, latency_ms: float) -> CameraFrames:
    """The accepted vision frames inside the static poses, with the robot's pose at each."""
    v = data.vision
    ok = v["accepted"].astype(bool) if len(v["capture_ns"]) else np.zeros(0, bool)
    vi = window_samples(win, v["capture_ns"], latency_ms, ok)
    idx = np.concatenate([np.asarray(i, int) for i in vi]) if vi else np.zeros(0, int)
    pose = np.concatenate([np.full(len(i), k) for k, i in enumerate(vi)]) if vi else np.zeros(0, int)
    R, p = interp_pose(
        v["capture_ns"][idx] - int(latency_ms * 1e6), data.robot_t_ns, data.R_base_tool, data.p_tip_base_m
    )
    return CameraFrames(
        pose=pose,
        R_base_tool=R,
        p_tip_base_m=p,
        n_left=v["n_left"][idx],
        n_right=v["n_right"][idx],
        junction_ray=v["junction_ray"][idx],
        junction_visible=v["junction_visible"][idx].astype(bool),
    )


def calibrate_block(
    data: CalibrationData, fits: tuple[str, ...] = BLOCK_FITS, tof_pose_sd_mm: float = 3.0
) -> tuple[Calibration, dict[str, Any]]:
    """Run `fits` on a recording with a robot reference; returns (calibration, report)."""
    require(data.has_robot, "calibration", f"{data.source}: no robot reference (topic bench/robot)")
    require(data.prior is not None, "calibration", "no starting constants: give --prior FILE")
    prior = data.prior
    win = static_windows(data.robot_t_ns, data.R_base_tool, data.p_tip_base_m)
    require(len(win) >= 3, "calibration", f"{data.source}: found {len(win)} static poses, need at least 3")
    report: dict[str, Any] = {"source": data.source, "static_poses": len(win)}
    new: dict[str, Any] = {}
    if "rcm" in fits:
        r = fit_rcm(win.p_tip_base_m, win.R_base_tool)
        new["rcm_base_m"] = r.rcm_base_m
        report["rcm"] = {
            "residual_mm": _r(r.residual_mm),
            "heldout_mm": _r(r.heldout_mm),
            "spread_deg": _r(r.spread_deg, 2),
        }
    R_tool_imu = prior.R_tool_imu
    if "mounting" in fits:
        R_tool_imu = new["R_tool_imu"] = mounting(data, win, prior, report)
        new["R_tool_imu_sd_deg"] = report["mounting"]["sd_deg"]
    if "accel" in fits:
        ai = window_samples(win, data.accel_t_ns, prior.latency_ms.get("accel", 0.0))
        keep = [k for k, i in enumerate(ai) if len(i) >= 10]
        a = np.array([data.accel_mps2[ai[k]].mean(0) for k in keep]).reshape(-1, 3)
        sd = np.array([np.linalg.norm(data.accel_mps2[ai[k]].std(0)) / np.sqrt(len(ai[k])) for k in keep])
        acc = fit_accel(a, win.R_base_tool[keep], R_tool_imu, sd)
        report["accel"] = {
            "bias_mps2": [_r(x, 5) for x in acc.bias_mps2],
            "scale": [_r(x, 6) for x in acc.scale],
            "misalignment": [_r(x, 6) for x in acc.misalignment],
            "sd": {k: [_r(x, 6) for x in v] for k, v in acc.sd.items()},
            "residual_deg": _r(acc.residual_deg),
            "heldout_deg": _r(acc.heldout_deg),
            "norm_error_frac": _r(acc.norm_error_frac, 6),
        }
    if "tof" in fits:
        ti = window_samples(win, data.tof_t_ns, prior.latency_ms.get("tof", 0.0), data.tof_valid)
        keep = [k for k, i in enumerate(ti) if len(i) >= 10]
        rng_mm = np.array([data.tof_raw_mm[ti[k]].mean() for k in keep])
        sd_mm = np.array([data.tof_raw_mm[ti[k]].std() for k in keep])
        n = np.array([len(ti[k]) for k in keep])
        p0 = TofModel(prior.tof_origin_tool_m, prior.tof_beam_tool, prior.tof_plane_normal_base, prior.tof_plane_h_m)
        t = fit_tof(rng_mm, sd_mm, n, win.R_base_tool[keep], win.p_tip_base_m[keep], p0, pose_sd_mm=tof_pose_sd_mm)
        new.update(
            tof_origin_tool_m=t.model.origin_tool_m,
            tof_beam_tool=t.model.beam_tool,
            tof_plane_normal_base=t.model.plane_normal_base,
            tof_plane_h_m=float(t.model.plane_h_m),
        )
        report["tof"] = {
            "residual_mm": _r(t.residual_mm),
            "heldout_mm": _r(t.heldout_mm),
            "prior_heldout_mm": _r(t.prior_heldout_mm),
            "sd": {k: _r(v) for k, v in t.sd.items()},
            "poses": t.poses,
        }
    if "camera" in fits or "vision_offset" in fits:
        frames = camera_frames(data, win, prior.latency_ms.get("camera", 0.0))
    if "camera" in fits:
        cam = fit_camera(
            frames,
            prior.T_base_camera,
            prior.junction_proximal_m - prior.vision_tip_offset_m,
            prior.shaft_radius_m,
        )
        # the pose and the junction-to-tip distance are fitted together and go together; the
        # vision offset fit below, if run, re-fits the distance through the new pose
        new.update(
            T_base_camera=cam.T_base_camera, junction_proximal_m=cam.junction_proximal_m, vision_tip_offset_m=0.0
        )
        report["camera"] = {
            "rotation_change_deg": _r(cam.rotation_change_deg),
            "position_change_mm": _r(cam.position_change_mm),
            "residual_mm": {k: _r(v) for k, v in cam.residual_mm.items()},
            "prior_residual_mm": {k: _r(v) for k, v in cam.prior_residual_mm.items()},
            "heldout_mm": {k: _r(v) for k, v in cam.heldout_mm.items()},
            "sd": {k: [_r(x) for x in v] for k, v in cam.sd.items()},
            "frames": cam.frames,
            "dropped": cam.dropped,
            "poses": cam.poses,
        }
    T_base_camera = new.get("T_base_camera", prior.T_base_camera)
    if "vision_offset" in fits:
        f = frames if "camera" in fits else camera_frames(data, win, prior.latency_ms.get("camera", 0.0))
        per_pose = []
        for k in range(len(win)):
            sel = (f.pose == k) & f.junction_visible
            per_pose.append(
                junction_offsets_m(
                    f.junction_ray[sel],
                    f.R_base_tool[sel],
                    f.p_tip_base_m[sel],
                    T_base_camera,
                    prior.junction_proximal_m,
                )
            )
        vo = fit_vision_offset(per_pose)
        # written as the junction-to-tip distance itself with a zero offset, so that a reader
        # computing the tip as J + (junction_proximal_m -/+ vision_tip_offset_m) u gets it right
        new["junction_proximal_m"] = prior.junction_proximal_m - vo.vision_tip_offset_m
        new["vision_tip_offset_m"] = 0.0
        report["vision_offset"] = {
            "offset_mm": _r(vo.vision_tip_offset_m * 1e3),
            "junction_to_tip_mm": _r((prior.junction_proximal_m - vo.vision_tip_offset_m) * 1e3),
            "heldout_mm": _r(vo.heldout_mm),
            "frames": vo.frames,
            "poses": vo.poses,
        }
    return dataclasses.replace(prior, **new), report
