"""Static-trial filter for the translation and rotation protocols (paper, "Error-State Kalman
Filter"): nominal state (R_base_tool, gyro bias b_g [rad/s, imu axes], insertion depth L [m],
the IMU's mounting error m [rad, tool x and y]), error state [dtheta (tool axes, right
perturbation), db_g, dL, dm] in R^9. Pure numpy, no I/O.

- gyro propagation R <- R Exp(M (w - b_g) dt), M = Exp(m) R_tool_imu the mounting as estimated;
- accelerometer direction M^T R^T e_z while |w - b_g| < 2 deg/s;
- vision: the two tangent-plane constraints n_i^T A u = 0 (A = R_camera_base, u = R e_s)
  and the junction depth (junction ray against the axis through the registered RCM);
- ToF: the ray-plane range rho = (h - m.(p + R o_s)) / (m.(R b_s)), p = r + L u.

The mounting error's two components across the shaft become observable once the tool turns: the
gyro turns the shaft about M's axes, and vision and gravity see where the shaft went. The
accelerometer's direction does not update the mounting directly (its Jacobian's mounting columns
are zero): at rest it would tell the mounting from the few poses a protocol repeats, through
pose-locked errors (0.21 deg per pose) as large as a lab's mounting error. The mounting is learnt
through its correlation with the attitude that the gyro's turns carry. The component along the
shaft is not observable (vision is blind to roll, and gravity cannot tell it from the tool's own
roll), nor does it change a relative rotation; it is left to the calibration.
Every update is gated on its innovation (chi-square) and counted by stream and reason. The
initial heading is chosen among the branches that satisfy the plane constraints by
reprojecting the shaft into the image (`initial_heading`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.fusion.eskf.kernels.so3 import exp_so3, skew
from tiplog.calibration import Calibration
from tiplog.geometry import rot_between
from tiplog.geometry.vision import closest_axis_point, p0_from_normals, ray_axis_intersection, trocar_gate

E_S = np.array([0.0, 0.0, 1.0])  # shaft axis in tool coordinates (distal)
G_MPS2 = 9.81
_DEG = math.pi / 180.0
_CHI2 = {1: 10.83, 2: 13.82, 3: 16.27}  # 99.9 %


@dataclass(frozen=True)
class StaticParams:
    """Noise model: per-update sigmas are held-out residuals inflated by sqrt(N_c) for N_c
    correlated samples (paper, "Noise model"); random walks per sqrt(s)."""

    gyro_noise_dps_rthz: float = 0.014
    gyro_bias_rw_dps_rts: float = 0.002
    gyro_bias_rw_dps_rts_per_radps: float = 0.35  # the bias moves in motion
    init_gyro_bias_dps: float = 0.05
    init_attitude_deg: float = 1.0
    init_heading_deg: float = 2.0
    init_depth_mm: float = 5.0
    depth_rw_still_mm_rts: float = 0.05  # inside a stationary window
    depth_rw_moving_mm_rts: float = 30.0  # elsewhere
    accel_sigma_deg: float = 3.0  # 0.21 deg held out x sqrt(~200 correlated samples)
    accel_max_rate_dps: float = 2.0
    plane_sigma_deg: float = 0.45  # 0.113 deg held out x sqrt(15)
    vision_depth_sigma_mm: float = 1.8  # 0.47 mm x sqrt(15)
    p0_sigma_mm: float = 0.0  # closest axis point off the line through the RCM; 0: off
    tof_sigma_mm: float = 30.0  # 3.04 mm pose-locked across poses x sqrt(100 samples per pose)
    junction_min_sin2: float = 0.45
    trocar_gate_mm: float = 0.0  # 0: off (the n_L x n_R line is ill-conditioned; the planes are gated on innovation)
    depth_reacquire_frames: int = 5  # this many vision depths in a row refused: the depth is reopened; 0: off
    # relative rotation between the windows (study.static_trials): the error of the
    # windows' own absolute attitudes (pose-locked: accelerometer 0.21 deg per pose, more in
    # roll) against the gyro's across the move per degree turned (gain, mounting, bias in motion);
    # relrot_absolute_deg 0 keeps the filter's own post-window attitude
    relrot_absolute_deg: float = 0.45
    relrot_gyro_per_deg: float = 0.003
    # the gyro's bias across the move: pinned at both windows' rest rates (W_pre's and W_post's
    # tails) and walked between them where the tool turned; False: W_pre's rest rate throughout
    relrot_bias_end: bool = True
    # prior sigma of the IMU's mounting error across the shaft, per axis (lab calibration:
    # a few tenths of a degree); 0: the calibration's mounting is taken as exact
    init_mount_deg: float = 0.3


@dataclass
class StaticState:
    t_ns: int
    R: np.ndarray  # R_base_tool
    bg: np.ndarray  # rad/s, imu axes
    L: float  # m
    P: np.ndarray  # (9, 9)
    mount: np.ndarray = field(default_factory=lambda: np.zeros(3))  # rad, tool axes (z stays 0)
    w_imu: np.ndarray = field(default_factory=lambda: np.zeros(3))  # latest gyro sample
    depth_refused: int = 0  # consecutive vision depths refused on innovation
    counts: dict[str, int] = field(default_factory=dict)

    def tip(self, rcm_base_m: np.ndarray) -> np.ndarray:
        """Tip position in base [m]: r + L u."""
        return rcm_base_m + self.L * (self.R @ E_S)


class StaticFilter:
    def __init__(self, calibration: Calibration, params: StaticParams | None = None):
        self.c = calibration
        self.p = params or StaticParams()
        self.A = calibration.R_base_camera.T  # base -> camera
        self.cam_base = calibration.p_base_camera_m
        self.still = False  # inside a stationary window (protocol timing): depth nearly constant

    def new_state(self, t_ns: int, R_base_tool: np.ndarray, depth_m: float) -> StaticState:
        p = self.p
        P = np.diag(
            [(p.init_attitude_deg * _DEG) ** 2] * 2
            + [(p.init_heading_deg * _DEG) ** 2]
            + [(p.init_gyro_bias_dps * _DEG) ** 2] * 3
            + [(p.init_depth_mm * 1e-3) ** 2]
            + [(p.init_mount_deg * _DEG) ** 2] * 2
        )
        return StaticState(int(t_ns), np.array(R_base_tool, float), np.zeros(3), float(depth_m), P)

    def R_tool_imu(self, s: StaticState) -> np.ndarray:
        """The IMU's mounting as estimated: Exp(m) R_tool_imu."""
        return exp_so3(s.mount) @ self.c.R_tool_imu

    # ------------------------------------------------------------------ propagation
    def propagate(self, s: StaticState, t_ns: int) -> None:
        """Carry the state to t_ns with the latest gyro sample (zero-order hold)."""
        dt = (int(t_ns) - s.t_ns) * 1e-9
        if dt <= 0.0:
            return
        p = self.p
        M = self.R_tool_imu(s)
        w_tool = M @ (s.w_imu - s.bg)
        Exp = exp_so3(w_tool * dt)
        s.R = s.R @ Exp
        F = np.eye(9)
        F[0:3, 0:3] = Exp.T
        F[0:3, 3:6] = -M * dt
        F[0:3, 7:9] = -skew(w_tool)[:, 0:2] * dt  # w_tool = Exp(dm) M w: dm x w_tool
        rate = float(np.linalg.norm(s.w_imu - s.bg))
        q_b = (p.gyro_bias_rw_dps_rts + p.gyro_bias_rw_dps_rts_per_radps * rate) * _DEG
        q_l = (p.depth_rw_still_mm_rts if self.still else p.depth_rw_moving_mm_rts) * 1e-3
        Q = np.diag([(p.gyro_noise_dps_rthz * _DEG) ** 2] * 3 + [q_b**2] * 3 + [q_l**2, 0.0, 0.0]) * dt
        s.P = F @ s.P @ F.T + Q
        s.t_ns = int(t_ns)

    def on_gyro(self, s: StaticState, t_ns: int, w_imu_radps: np.ndarray) -> None:
        self.propagate(s, t_ns)
        s.w_imu = np.asarray(w_imu_radps, float)

    # ------------------------------------------------------------------ updates
    def _update(self, s: StaticState, y: np.ndarray, H: np.ndarray, Rn: np.ndarray, name: str) -> bool:
        S = H @ s.P @ H.T + Rn
        try:
            Si = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            _bump(s.counts, f"rejected:{name}:singular")
            return False
        nis = float(y @ Si @ y)
        if not math.isfinite(nis) or nis > _CHI2[min(len(y), 3)]:
            _bump(s.counts, f"rejected:{name}:innovation")
            return False
        K = s.P @ H.T @ Si
        dx = K @ y
        s.R = s.R @ exp_so3(dx[0:3])
        s.bg = s.bg + dx[3:6]
        s.L = float(s.L + dx[6])
        s.mount[0:2] += dx[7:9]
        I_KH = np.eye(9) - K @ H
        s.P = I_KH @ s.P @ I_KH.T + K @ Rn @ K.T
        _bump(s.counts, f"updates:{name}")
        return True

    def update_accel(self, s: StaticState, f_imu_mps2: np.ndarray) -> bool:
        """Gravity direction, only while the tool is still (|w| below the threshold)."""
        if np.linalg.norm(s.w_imu - s.bg) >= self.p.accel_max_rate_dps * _DEG:
            _bump(s.counts, "rejected:accel:moving")
            return False
        f = np.asarray(f_imu_mps2, float)
        z = f / np.linalg.norm(f)
        v = s.R.T @ np.array([0.0, 0.0, 1.0])
        M = self.R_tool_imu(s)
        H = np.zeros((3, 9))
        H[:, 0:3] = M.T @ skew(v)
        Rn = np.eye(3) * (self.p.accel_sigma_deg * _DEG) ** 2
        return self._update(s, z - M.T @ v, H, Rn, "accel")

    def update_vision(self, s: StaticState, n_left: np.ndarray, n_right: np.ndarray, ray: np.ndarray | None) -> None:
        """Tangent-plane constraints and, when the junction ray is given and well
        conditioned, the junction depth; frames failing the trocar gate are skipped."""
        c = self.c
        rcm_cam = self.A @ (c.rcm_base_m - self.cam_base)
        gate_m = self.p.trocar_gate_mm * 1e-3
        if gate_m > 0 and not bool(trocar_gate(n_left, n_right, c.shaft_radius_m, rcm_cam, gate_m)[1]):
            _bump(s.counts, "rejected:vision:trocar_gate")
            return
        N = np.stack([n_left, n_right])
        AR = self.A @ s.R
        H = np.zeros((2, 9))
        H[:, 0:3] = -(N @ AR) @ skew(E_S)
        y = -(N @ AR @ E_S)
        self._update(s, y, H, np.eye(2) * (self.p.plane_sigma_deg * _DEG) ** 2, "vision_planes")
        if self.p.p0_sigma_mm > 0:
            # the closest axis point P0 (well conditioned) lies on the line through the RCM:
            # its offset normal to u observes u's component within the viewing plane too
            d = c.R_base_camera @ p0_from_normals(n_left, n_right, c.shaft_radius_m) + self.cam_base - c.rcm_base_m
            u = s.R @ E_S
            du = -s.R @ skew(E_S)  # d u / d dtheta
            H = np.zeros((3, 9))
            H[:, 0:3] = -(u @ d) * du - np.outer(u, d @ du)
            y = -(d - u * (u @ d))
            self._update(s, y, H, np.eye(3) * (self.p.p0_sigma_mm * 1e-3) ** 2, "vision_p0")
        if ray is None:
            return
        u_cam = self.A @ s.R @ E_S
        depth, _, cond = ray_axis_intersection(np.asarray(ray, float), rcm_cam, u_cam)
        if not cond >= self.p.junction_min_sin2:
            _bump(s.counts, "rejected:vision_depth:conditioning")
            return
        L_vis = float(depth) + c.junction_proximal_m - c.vision_tip_offset_m
        H = np.zeros((1, 9))
        H[0, 6] = 1.0
        Rn = np.array([[(self.p.vision_depth_sigma_mm * 1e-3) ** 2]])
        if self._update(s, np.array([L_vis - s.L]), H, Rn, "vision_depth"):
            s.depth_refused = 0
            return
        s.depth_refused += 1
        if 0 < self.p.depth_reacquire_frames <= s.depth_refused:
            # the depth converged to a wrong value (the ToF's pose-locked error) and now refuses
            # the vision depth that would correct it: reopen its variance and take this frame
            s.P[6, :] = 0.0
            s.P[:, 6] = 0.0
            s.P[6, 6] = (self.p.init_depth_mm * 1e-3) ** 2
            s.depth_refused = 0
            _bump(s.counts, "reacquire:depth")
            self._update(s, np.array([L_vis - s.L]), H, Rn, "vision_depth")

    def tof_range(self, R: np.ndarray, L: float) -> float:
        """Predicted raw range [m] of the ray-plane model at orientation R and depth L."""
        c = self.c
        p = c.rcm_base_m + L * (R @ E_S)
        m = c.tof_plane_normal_base
        return float((c.tof_plane_h_m - m @ (p + R @ c.tof_origin_tool_m)) / (m @ (R @ c.tof_beam_tool)))

    def update_tof(self, s: StaticState, range_m: float) -> bool:
        h0 = self.tof_range(s.R, s.L)
        H = np.zeros((1, 9))
        eps = 1e-6
        for k in range(3):
            d = np.zeros(3)
            d[k] = eps
            H[0, k] = (self.tof_range(s.R @ exp_so3(d), s.L) - h0) / eps
        H[0, 6] = (self.tof_range(s.R, s.L + eps) - h0) / eps
        Rn = np.array([[(self.p.tof_sigma_mm * 1e-3) ** 2]])
        return self._update(s, np.array([range_m - h0]), H, Rn, "tof")

    def depth_from_tof(self, R: np.ndarray, range_m: float) -> float:
        """Depth L [m] that makes the ray-plane model give `range_m` at orientation R."""
        a, b = self.tof_range(R, 0.0), self.tof_range(R, 1.0)
        return (range_m - a) / (b - a)


def _bump(d: dict[str, int], key: str) -> None:
    d[key] = d.get(key, 0) + 1


def inclined_rotation(f_imu_mps2: np.ndarray, R_tool_imu: np.ndarray) -> np.ndarray:
    """A R_base_tool whose imu sees the mean specific force f as straight up (heading 0)."""
    R_base_imu = rot_between(np.asarray(f_imu_mps2, float), np.array([0.0, 0.0, 1.0]))
    return R_base_imu @ R_tool_imu.T


def _rz(psi: np.ndarray) -> np.ndarray:
    c, s = np.cos(psi), np.sin(psi)
    z, o = np.zeros_like(psi), np.ones_like(psi)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def heading_branches(R0: np.ndarray, normals: np.ndarray, A: np.ndarray, step_deg: float = 0.1) -> list[float]:
    """Headings psi [rad] about base z at which R = Rz(psi) R0 satisfies the plane constraints
    best locally (the branches): local minima of sum (n^T A Rz(psi) R0 e_s)^2 over frames.
    normals: (F, 2, 3) per frame (n_L, n_R), camera frame."""
    psi = np.radians(np.arange(0.0, 360.0, step_deg))
    u = _rz(psi) @ (R0 @ E_S)  # (K, 3)
    res = np.einsum("fij,kj->kfi", normals.reshape(-1, 2, 3) @ A, u)
    cost = (res**2).sum(axis=(1, 2))
    is_min = (cost < np.roll(cost, 1)) & (cost <= np.roll(cost, -1))
    order = np.argsort(cost[is_min])
    return [float(x) for x in psi[is_min][order][:4]]


def reprojection_px(calib: Calibration, R: np.ndarray, normals: np.ndarray) -> float:
    """How well the shaft predicted by R (the axis through the RCM along R e_s) reprojects
    onto the observed silhouettes, mean over frames [px]: the image distance of points of the
    predicted shaft from the observed axis line (midline, plane normal n_L - n_R), plus the
    image distance between the predicted and the observed closest axis point P0 (fixes where
    along that line the shaft lies: a branch mirrored within the camera's plane of view
    projects onto the same line). inf if the predicted shaft is behind the camera; a frame whose
    observed P0 lies behind the camera (an outlier no shaft in view can give) is left out, and
    with no frame left the score is inf."""
    A = calib.R_base_camera.T
    r_c = A @ (calib.rcm_base_m - calib.p_base_camera_m)
    u_c = A @ R @ E_S
    X = r_c[None, :] + u_c[None, :] * np.linspace(0.08, 0.14, 10)[:, None]
    p0_pred = closest_axis_point(r_c, u_c)
    p0_obs = p0_from_normals(normals[:, 0, :], normals[:, 1, :], calib.shaft_radius_m)
    front = p0_obs[:, 2] > 0
    if np.any(X[:, 2] <= 0) or p0_pred[2] <= 0 or not front.any():
        return math.inf
    normals, p0_obs = normals[front], p0_obs[front]
    mid = normals[:, 0, :] - normals[:, 1, :]
    mid = mid / np.linalg.norm(mid[:, :2], axis=1, keepdims=True)
    line = np.mean(np.abs((X / X[:, 2:3]) @ mid.T))
    point = np.mean(np.linalg.norm(p0_obs[:, :2] / p0_obs[:, 2:3] - p0_pred[:2] / p0_pred[2], axis=1))
    return float((line + point) * calib.intrinsics["fx"])


def initial_heading(calib: Calibration, f_imu_mps2: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """R_base_tool from the mean specific force (inclination) and the vision frames of one
    stationary window (heading): the plane-constraint branch that reprojects best.
    Returns (R, reprojection errors [px] of the branches tried, best first)."""
    R0 = inclined_rotation(f_imu_mps2, calib.R_tool_imu)
    A = calib.R_base_camera.T
    cands = [_rz(np.array(p)) @ R0 for p in heading_branches(R0, normals, A)]
    scores = [reprojection_px(calib, R, normals) for R in cands]
    order = np.argsort(scores)
    return cands[int(order[0])], [scores[i] for i in order]
