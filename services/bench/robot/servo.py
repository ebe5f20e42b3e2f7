"""The paper's remote-centre-of-motion servo, run at a fixed rate on the kinematic FR3.

Commands are tip targets p_raw(t) [m, base], their rates, and a roll angle about the shaft.
Each target is projected onto the port (direction u_d from the RCM r, depth clipped to
[L_min, L_max]); the tip twist is

    v = k_p (p_d - p) + k_f dp_d/dt          (tip linear velocity, |v| <= v_max)
    w = (u x v) / L + k_rcm u x u_c + (droll_d + k_roll (roll_d - roll)) u

The first term of w pivots the shaft about r with exactly the tip velocity v (w x L u = v
perpendicular to u), so the line through the tip keeps passing through r; the second turns the
shaft about the tip onto u_c and removes any residual line offset. With `correction="target"` u_c
is the paper's u_d (the target's port direction); with `correction="tip"` (default) it is the
port direction through the current tip, (p - r)/|p - r|, so that tracking lag never turns into
RCM error. Damped least squares on the 6x7 tip Jacobian (LOCAL_WORLD_ALIGNED at the tool frame)
turns [v; w] into joint rates, a posture term acts in its null space, and joint rates are
scaled to the velocity limits and clamped so that positions stay inside the limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from services.bench.robot.fr3 import Fr3Kinematics


@dataclass(frozen=True)
class ServoParams:
    """Gains [1/s], damping [-], limits; all in SI units."""

    k_p_per_s: float = 30.0
    k_f: float = 1.0
    k_rcm_per_s: float = 30.0
    k_roll_per_s: float = 20.0
    damping: float = 0.005
    posture_gain_per_s: float = 2.0
    posture_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    tip_speed_max_mps: float = 0.05
    L_min_m: float = 0.105
    L_max_m: float = 0.175
    joint_margin_rad: float = 0.01
    rate_hz: float = 1000.0
    correction: Literal["tip", "target"] = "tip"


def project_onto_port(
    p_raw_m: np.ndarray, dp_raw_mps: np.ndarray, r_m: np.ndarray, L_min_m: float, L_max_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Targets (N, 3) and rates (N, 3) -> projected p_d, dp_d and port directions u_d (N, 3).

    Only the direction from r and the clipped depth are kept: p_d = r + clip(|p - r|) u_d.
    """
    d = np.asarray(p_raw_m, float) - r_m
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(n < 1e-6):
        raise ValueError("p_raw_m: a tip target coincides with the RCM; its port direction is undefined")
    u_d = d / n
    L_d = np.clip(n, L_min_m, L_max_m)
    dp = np.asarray(dp_raw_mps, float)
    dn = np.sum(u_d * dp, axis=-1, keepdims=True)
    du = (dp - dn * u_d) / n
    clipped = (n < L_min_m) | (n > L_max_m)
    dL = np.where(clipped, 0.0, dn)
    return r_m + L_d * u_d, dL * u_d + L_d * du, u_d


def roll_about_shaft(R: np.ndarray, R_neutral: np.ndarray) -> np.ndarray:
    """Roll [rad] of R_base_tool (..., 3, 3) about its shaft relative to R_neutral.

    The neutral x axis is carried to the current shaft by the minimal rotation u0 -> u (so pure
    pitch/yaw has zero roll); the roll is the signed angle from it to the current x axis about u.
    """
    u0, x0 = R_neutral[:, 2], R_neutral[:, 0]
    u, x = R[..., :, 2], R[..., :, 0]
    k = np.cross(u0, u)
    c = np.sum(u * u0, axis=-1)[..., None]
    x_ref = x0 + np.cross(k, x0) + np.cross(k, np.cross(k, x0)) / (1.0 + c)
    s = np.sum(u * np.cross(x_ref, x), axis=-1)
    return np.arctan2(s, np.sum(x_ref * x, axis=-1))


@dataclass
class ServoLog:
    """Per-sample state at the servo rate: q (N, 7) [rad], dq (N, 7) [rad/s], R (N, 3, 3), p (N, 3) [m]."""

    q_rad: np.ndarray
    dq_radps: np.ndarray
    R_base_tool: np.ndarray
    p_tip_base_m: np.ndarray


class RcmServo:
    """Kinematic FR3 driven by the RCM servo; `run` integrates a whole command sequence."""

    def __init__(
        self,
        kin: Fr3Kinematics,
        r_base_m: np.ndarray,
        R_neutral: np.ndarray,
        q_posture_rad: np.ndarray,
        params: ServoParams | None = None,
    ) -> None:
        self.kin = kin
        self.p = params or ServoParams()
        self.r = np.asarray(r_base_m, float).copy()
        self.R_neutral = np.asarray(R_neutral, float).copy()
        self.q_posture = np.asarray(q_posture_rad, float).copy()
        if len(self.p.posture_weights) != 7:
            raise ValueError("posture_weights must have 7 elements")
        m = self.p.joint_margin_rad
        self.q_lo = kin.q_min_rad + m
        self.q_hi = kin.q_max_rad - m

    def run(
        self,
        q0_rad: np.ndarray,
        p_raw_m: np.ndarray,
        dp_raw_mps: np.ndarray,
        roll_d_rad: np.ndarray,
        droll_d_radps: np.ndarray,
    ) -> ServoLog:
        """Integrate N steps from q0; sample k holds the state at t_k and the rate applied after it."""
        N = len(p_raw_m)
        P = self.p
        dt = 1.0 / P.rate_hz
        p_d, dp_d, u_d = project_onto_port(p_raw_m, dp_raw_mps, self.r, P.L_min_m, P.L_max_m)
        ff = np.concatenate([P.k_p_per_s * p_d, P.k_f * dp_d], axis=1).tolist()
        u_d = u_d.tolist()
        roll_d = np.asarray(roll_d_rad, float).tolist()
        droll_d = np.asarray(droll_d_radps, float).tolist()
        rx, ry, rz = self.r.tolist()
        x0x, x0y, x0z = self.R_neutral[:, 0].tolist()
        u0x, u0y, u0z = self.R_neutral[:, 2].tolist()
        kp, krcm, kroll, vmax = P.k_p_per_s, P.k_rcm_per_s, P.k_roll_per_s, P.tip_speed_max_mps
        use_tip = P.correction == "tip"
        lam2I = P.damping**2 * np.eye(6)
        Wk = P.posture_gain_per_s * np.asarray(P.posture_weights, float)
        dq_max = self.kin.dq_max_radps
        q_lo, q_hi, q_post = self.q_lo, self.q_hi, self.q_posture
        x = np.empty(6)
        q_log = np.empty((N, 7))
        dq_log = np.empty((N, 7))
        R_log = np.empty((N, 3, 3))
        p_log = np.empty((N, 3))
        q = np.asarray(q0_rad, float).copy()
        pose_and_jacobian = self.kin.pose_and_jacobian
        solve = np.linalg.solve
        for k in range(N):
            R, p_arr, J = pose_and_jacobian(q)
            R_log[k] = R
            p_log[k] = p_arr
            q_log[k] = q
            px, py, pz = p_arr.tolist()
            (xx, _, ux), (xy, _, uy), (xz, _, uz) = R.tolist()
            dx, dy, dz = px - rx, py - ry, pz - rz
            L = dx * ux + dy * uy + dz * uz
            f = ff[k]
            vx = f[0] - kp * px + f[3]
            vy = f[1] - kp * py + f[4]
            vz = f[2] - kp * pz + f[5]
            s = math.sqrt(vx * vx + vy * vy + vz * vz)
            if s > vmax:
                g = vmax / s
                vx, vy, vz = vx * g, vy * g, vz * g
            if use_tip:
                n = math.sqrt(dx * dx + dy * dy + dz * dz)
                cx, cy, cz = dx / n, dy / n, dz / n
            else:
                cx, cy, cz = u_d[k]
            # Roll about the shaft: neutral x carried by the minimal rotation u0 -> u.
            kx, ky, kz = u0y * uz - u0z * uy, u0z * ux - u0x * uz, u0x * uy - u0y * ux
            c1 = 1.0 + u0x * ux + u0y * uy + u0z * uz
            ax, ay, az = ky * x0z - kz * x0y, kz * x0x - kx * x0z, kx * x0y - ky * x0x
            bx, by, bz = ky * az - kz * ay, kz * ax - kx * az, kx * ay - ky * ax
            fx, fy, fz = x0x + ax + bx / c1, x0y + ay + by / c1, x0z + az + bz / c1
            sn = ux * (fy * xz - fz * xy) + uy * (fz * xx - fx * xz) + uz * (fx * xy - fy * xx)
            roll_err = roll_d[k] - math.atan2(sn, fx * xx + fy * xy + fz * xz)
            roll_err = (roll_err + math.pi) % (2.0 * math.pi) - math.pi
            wr = droll_d[k] + kroll * roll_err
            x[0], x[1], x[2] = vx, vy, vz
            x[3] = (uy * vz - uz * vy) / L + krcm * (uy * cz - uz * cy) + wr * ux
            x[4] = (uz * vx - ux * vz) / L + krcm * (uz * cx - ux * cz) + wr * uy
            x[5] = (ux * vy - uy * vx) / L + krcm * (ux * cy - uy * cx) + wr * uz
            z = Wk * (q_post - q)
            Y = solve(J @ J.T + lam2I, np.stack([x, J @ z], axis=1))
            dq = J.T @ (Y[:, 0] - Y[:, 1]) + z
            # Velocity limits: scale the whole vector (keeps the twist's direction);
            # position limits: clamp each joint so the next sample stays inside.
            ratio = np.max(np.abs(dq) / dq_max)
            if ratio > 1.0:
                dq /= ratio
            dq = np.clip(dq, (q_lo - q) / dt, (q_hi - q) / dt)
            dq_log[k] = dq
            q = q + dq * dt
        return ServoLog(q_rad=q_log, dq_radps=dq_log, R_base_tool=R_log, p_tip_base_m=p_log)
