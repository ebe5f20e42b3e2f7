"""Measurement-tier vision: what the vision service would report for each camera frame,
straight from the true shaft geometry and an error model sized to the paper.

Per frame (15 fps, capture stamped on host arrival = exposure + camera latency): the two
tangent-plane normals of the shaft cylinder seen from the camera centre, perturbed by white
and pose-locked noise (0.11 deg held out in total); the junction (about 4 mm proximal of
the true tip) as undistorted pixel and ray, its depth perturbed (0.47 mm held out); the
consistency-gate measures, drawn wider in fast image motion (64-78 % accepted in free
motion); occasional wrong segmentations that pass the gate (a line several degrees off,
which the estimator's trocar gate must catch); rare gross junction errors that pass the gate
(as the pixel tier shows); junction hidden or ill-conditioned
(1 - (d.u)^2 < 0.45) frames; ~113 ms processing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from services.bench.scenario import Scenario
from services.bench.sensors import vision_motion as vm
from services.bench.sensors.calibration import BenchConstants
from services.bench.sensors.device import Kinematics, _interp, _interp_R, arrival, pose_field_at
from services.bench.sensors.pose_field import PoseField
from tiplog.geometry import vision as vg


@dataclass
class VisionFrames:
    """Arrays over frames (n,): stamps [ns], geometry in the camera frame [m], pixels
    undistorted, the gate measures, and the outcome."""

    t_true_ns: np.ndarray
    capture_ns: np.ndarray
    processed_ns: np.ndarray
    processing_ms: np.ndarray
    accepted: np.ndarray
    reject_reason: list[str]
    n_left: np.ndarray
    n_right: np.ndarray
    axis_point_m: np.ndarray
    junction_px: np.ndarray
    junction_ray: np.ndarray
    junction_visible: np.ndarray
    mask_iou: np.ndarray
    line_angle_deg: np.ndarray
    lateral_px: np.ndarray
    junction_diff_px: np.ndarray
    line_residual_px: np.ndarray
    wrong_segmentation: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_true_ns)


def junction_outliers(
    rng: np.random.Generator, n: int, prob: float, range_mm: tuple[float, float], enabled: bool = True
) -> np.ndarray:
    """Per-frame gross junction depth errors [m] along the axis (mostly zero), each frame with
    probability `prob`, of a size uniform in `range_mm` and either sign; none when not enabled
    (an error-free configuration: wrong_seg_prob = 0). Drawn from a child generator, so every
    other draw of a seed is what it was before this term existed."""
    if not enabled or prob <= 0:
        return np.zeros(n)
    child = rng.spawn(1)[0]
    hit = child.random(n) < prob
    mag = child.uniform(*range_mm, n) * child.choice([-1.0, 1.0], n) * 1e-3
    return np.where(hit, mag, 0.0)


def frame_times(sc: Scenario, t_end_ns: int, rng: np.random.Generator) -> np.ndarray:
    """Exposure times [ns] of the camera's frames (its own clock, small jitter)."""
    period = 1e9 / sc.camera.fps
    k = np.arange(int((t_end_ns - 2e6) / period))
    t = rng.uniform(0, period) + k * period + rng.normal(size=len(k)) * sc.camera.frame_jitter_us * 1e3
    return np.maximum.accumulate(np.clip(np.round(t), 0, t_end_ns - 1)).astype(np.int64)


def _project_undist(sc: Scenario, x_cam: np.ndarray) -> np.ndarray:
    c = sc.camera
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([c.fx * x_cam[..., 0] / x_cam[..., 2] + c.cx, c.fy * x_cam[..., 1] / x_cam[..., 2] + c.cy], -1)


def _in_image(sc: Scenario, x_cam: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
    uv = sc.camera.model().project(x_cam)
    c = sc.camera
    ok = (x_cam[..., 2] > 0.01) & np.all(np.isfinite(uv), -1)
    return (
        ok
        & (uv[..., 0] >= margin_px)
        & (uv[..., 0] <= c.width - 1 - margin_px)
        & (uv[..., 1] >= margin_px)
        & (uv[..., 1] <= c.height - 1 - margin_px)
    )


def _visible_length_px(sc: Scenario, a_cam: np.ndarray, b_cam: np.ndarray, n_pts: int = 41) -> np.ndarray:
    """Length in pixels of the segment a-b (camera frame, (n, 3)) inside the image."""
    s = np.linspace(0.0, 1.0, n_pts)
    pts = a_cam[:, None, :] + s[None, :, None] * (b_cam - a_cam)[:, None, :]
    uv = sc.camera.model().project(pts)
    inside = _in_image(sc, pts)
    seg = np.linalg.norm(np.diff(uv, axis=1), axis=-1)
    both = inside[:, 1:] & inside[:, :-1]
    return np.where(both, np.nan_to_num(seg), 0.0).sum(1)


def _junction_cam(kin: Kinematics, const: BenchConstants, t_ns: np.ndarray) -> np.ndarray:
    """The true junction in the camera frame [m] at times t_ns (n, 3)."""
    tq = np.clip(t_ns, kin.t_ns[0], kin.t_ns[-1])
    R = _interp_R(tq, kin.t_ns, kin.R_base_tool)
    J = _interp(tq, kin.t_ns, kin.p_tip_base_m) - const.junction_proximal_m * R[:, :, 2]
    return (J - const.T_base_camera[:3, 3]) @ const.T_base_camera[:3, :3]


def simulate_vision(kin: Kinematics, sc: Scenario, const: BenchConstants, rng: np.random.Generator) -> VisionFrames:
    """Vision observations for every camera frame of the session (true constants in, noisy
    observations out)."""
    v, cam = sc.vision, sc.camera
    t = frame_times(sc, int(kin.t_ns[-1]), rng)
    n = len(t)
    R = _interp_R(t, kin.t_ns, kin.R_base_tool)
    p = _interp(t, kin.t_ns, kin.p_tip_base_m)
    A = const.T_base_camera[:3, :3].T  # base -> camera
    c = const.T_base_camera[:3, 3]
    u_c = (R[:, :, 2]) @ A.T
    J_base = p - const.junction_proximal_m * R[:, :, 2]
    J_c = (J_base - c) @ A.T
    rcm_c = (const.rcm_base_m - c) @ A.T
    rho = const.shaft_radius_m
    p0_true = vg.closest_axis_point(J_c, u_c)
    n_l0, n_r0 = vg.tangent_plane_normals(p0_true, u_c, rho)

    # tangent-plane noise: white per frame + pose-locked (4 angles: L/R x along-u/offset)
    fld = PoseField(rng, 4, np.radians(v.plane_pose_deg), np.radians(v.pose_corr_deg), v.pose_corr_m)
    pose_ang = pose_field_at(fld, kin, t)
    white = rng.normal(size=(n, 4)) * np.radians(v.plane_white_deg)
    ang = pose_ang + white
    wrong = rng.random(n) < v.wrong_seg_prob
    lo, hi = np.radians(v.wrong_seg_deg[0]), np.radians(v.wrong_seg_deg[1])
    which = rng.integers(0, 2, n)
    big = rng.uniform(lo, hi, n) * rng.choice([-1.0, 1.0], n)

    # junction: depth error along the axis (white + pose-locked), lateral pixel noise
    jfld = PoseField(rng, 1, v.junction_depth_pose_mm * 1e-3, np.radians(v.pose_corr_deg), v.pose_corr_m)
    dj_pose = pose_field_at(jfld, kin, t)[:, 0]
    dj_white = rng.normal(size=n) * v.junction_depth_white_mm * 1e-3
    dj = dj_pose + dj_white
    j_out = junction_outliers(rng, n, v.junction_outlier_prob, v.junction_outlier_mm, v.wrong_seg_prob > 0)

    # image speed of the junction over one frame period
    t_next = np.minimum(t + int(1e9 / cam.fps), kin.t_ns[-1])
    u_next = _interp_R(t_next, kin.t_ns, kin.R_base_tool)[:, :, 2]
    J_next = (_interp(t_next, kin.t_ns, kin.p_tip_base_m) - const.junction_proximal_m * u_next - c) @ A.T
    speed = np.nan_to_num(np.linalg.norm(_project_undist(sc, J_next) - _project_undist(sc, J_c), axis=1))

    # motion terms (exposure blur, speed, validated range, dropouts) from a child generator
    moving = vm.motion_enabled(v)
    mrng = rng.spawn(1)[0] if moving else None
    blank = hide_burst = np.zeros(n, bool)
    # the frame's own motion error in units of each gate measure's rest spread (zero at rest)
    s_rest = v.metric_scale_rest
    z_line = z_lat = z_junction = np.zeros(n)
    extra: dict[str, np.ndarray] = {}
    if mrng is not None:
        mot = vm.image_motion(
            lambda x: _project_undist(sc, x),
            _junction_cam(kin, const, t - int(v.exposure_ms * 5e5)),
            _junction_cam(kin, const, t + int(v.exposure_ms * 5e5)),
            J_c,
            u_c,
            speed,
        )
        u_neutral = np.asarray(sc.motion.R_neutral())[:, 2]
        depth_mm = ((p - const.rcm_base_m) * R[:, :, 2]).sum(1) * 1e3
        tilt_deg = np.degrees(np.arccos(np.clip(R[:, :, 2] @ u_neutral, -1.0, 1.0)))
        g = vm.range_growth(v, depth_mm, tilt_deg)
        # white plane noise grows with the edge blur and the range; image motion adds its own
        grow = np.sqrt(np.maximum((g * vm.edge_factor(v, mot)) ** 2 - 1.0, 0.0))
        extra_w = mrng.normal(size=(n, 4)) * (np.radians(v.plane_white_deg) * grow)[:, None]
        extra_w += mrng.normal(size=(n, 4)) * np.radians(v.plane_speed_deg_per_px * speed)[:, None]
        ang = ang + extra_w + pose_ang * (g - 1.0)[:, None]
        z_line = np.degrees(np.abs(extra_w[:, 0])) / (s_rest * v.gate_line_angle_deg)
        z_lat = np.abs(extra_w[:, 1]) * cam.fx / (s_rest * v.gate_lateral_px)
        dj_motion = vm.junction_axial_error_m(v, mot, g, mrng) + dj * (g - 1.0)
        dj = dj + dj_motion
        bias_m = v.junction_blur_bias * np.abs(mot.blur_axial_px) / mot.px_per_m_axial
        z_junction = np.abs(dj_motion - bias_m) * mot.px_per_m_axial / (s_rest * v.gate_junction_px)
        blank, hide_burst, bursts = vm.dropouts(v, t, mrng)
        extra.update(
            {
                "blur_axial_px": mot.blur_axial_px,
                "blur_across_px": mot.blur_across_px,
                "range_growth": g,
                "dropout_frame": blank,
                "dropout_junction": hide_burst,
            }
        )
    ang[:, 0] += np.where(wrong & (which == 0), big, 0.0)
    ang[:, 2] += np.where(wrong & (which == 1), big, 0.0)
    n_l = vg.tilt_normal(n_l0, ang[:, 0], ang[:, 1], u_c)
    n_r = vg.tilt_normal(n_r0, ang[:, 2], ang[:, 3], u_c)
    p0 = vg.p0_from_normals(n_l, n_r, rho)

    J_obs = J_c + (dj + j_out)[:, None] * u_c
    if v.junction_across_mm > 0:
        az = np.radians(v.junction_across_azimuth_deg)
        across_tool = v.junction_across_mm * 1e-3 * np.array([np.cos(az), np.sin(az), 0.0])
        J_obs = J_obs + (R @ across_tool) @ A.T
    uv = _project_undist(sc, J_obs) + rng.normal(size=(n, 2)) * v.junction_lateral_px
    ray = np.stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(n)], -1)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    cond = 1.0 - np.einsum("ij,ij->i", ray, u_c) ** 2
    j_in = _in_image(sc, J_c, margin_px=5.0)
    hidden = rng.random(n) < v.junction_hidden_prob
    j_vis = j_in & ~hidden & ~hide_burst & (cond >= v.junction_min_sin2)

    # shaft visibility: the segment from the junction back to the port
    L_vis = _visible_length_px(sc, J_c, rcm_c)
    shaft_ok = (L_vis >= v.min_visible_px) & np.all(np.isfinite(n_l0), 1) & (J_c[:, 2] > 0)

    # consistency gate: measures spread wider with image motion (blur, segmentation lag) and,
    # with gate_quality_weight, add the frame's own motion error to their rest spread
    s = v.metric_scale_rest * (1.0 + v.metric_scale_per_px * np.minimum(speed, 500.0))
    w = v.gate_quality_weight
    z_iou = np.sqrt((z_line**2 + z_lat**2 + z_junction**2) / 3.0)
    line_angle = vm.gate_measure(z_line, rng.normal(size=n), w) * s * v.gate_line_angle_deg
    lateral = vm.gate_measure(z_lat, rng.normal(size=n), w) * s * v.gate_lateral_px
    jdiff = vm.gate_measure(z_junction, rng.normal(size=n), w) * s * v.gate_junction_px
    iou = 1.0 - vm.gate_measure(z_iou, rng.normal(size=n), w) * s * (1.0 - v.gate_iou_min)
    # a wrong segmentation that both labeler and network share still passes the gate
    line_angle[wrong] *= 0.3
    lateral[wrong] *= 0.3
    jdiff[wrong] *= 0.3
    iou[wrong] = 1.0 - (1.0 - iou[wrong]) * 0.3
    fails = np.stack(
        [iou < v.gate_iou_min, line_angle >= v.gate_line_angle_deg, lateral >= v.gate_lateral_px]
        + [jdiff >= v.gate_junction_px],
        1,
    )
    names = np.array(["gate:mask_iou", "gate:line_angle", "gate:lateral", "gate:junction"])
    accepted = shaft_ok & ~blank & ~fails.any(1)
    reasons = [
        "" if a else ("shaft_not_visible" if not ok else ("dropout" if b else str(names[f.argmax()])))
        for a, ok, b, f in zip(accepted, shaft_ok, blank, fails, strict=True)
    ]
    cap = arrival(t, cam.latency_ms, cam.latency_jitter_ms, rng)
    proc_ms = np.clip(v.processing_ms + rng.normal(size=n) * v.processing_jitter_ms, 0.3 * v.processing_ms, None)
    processed = cap + np.round(proc_ms * 1e6).astype(np.int64)
    zero = np.zeros((n, 3))
    vis = shaft_ok[:, None]
    return VisionFrames(
        t_true_ns=t,
        capture_ns=cap,
        processed_ns=np.maximum.accumulate(processed),
        processing_ms=proc_ms,
        accepted=accepted,
        reject_reason=reasons,
        n_left=np.where(vis, np.nan_to_num(n_l), zero),
        n_right=np.where(vis, np.nan_to_num(n_r), zero),
        axis_point_m=np.where(vis, np.nan_to_num(p0), zero),
        junction_px=np.where(j_vis[:, None], uv, 0.0),
        junction_ray=np.where(j_vis[:, None], ray, zero),
        junction_visible=j_vis & shaft_ok,
        mask_iou=np.clip(iou, 0.0, 1.0),
        line_angle_deg=line_angle,
        lateral_px=lateral,
        junction_diff_px=jdiff,
        line_residual_px=np.abs(rng.normal(size=n)) * 0.25 + 0.1,
        wrong_segmentation=wrong,
        extra={
            "image_speed_px": speed,
            "junction_cond": cond,
            "visible_px": L_vis,
            "junction_outlier_m": j_out,
            "junction_depth_err_m": dj,
            **extra,
        },
    )
