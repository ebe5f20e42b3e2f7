"""Propagation of the nominal state and the covariance over one step: `propagate`, the same
with the latest samples held across a stalled host (`propagate_held`), and the step's
transition matrix for the smoother (`transition`). The covariance's product F P F^T is written
out over F's few non-zero blocks; the error state as in `layout`."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import mm, mv
from services.fusion.eskf.kernels.so3 import cross, exp_into, skew
from services.fusion.eskf.layout import (
    GK_BG_RW,
    GK_BG_RW_PER_RADPS,
    GK_BRHO_PER_RAD,
    GK_IMU_GAP_S,
    GK_NO_IMU_Q,
    N,
)


@njit(cache=True)
def lever_accel(w_tool: np.ndarray, alpha_tool: np.ndarray, r_lever_tool: np.ndarray) -> np.ndarray:
    """alpha x r + w x (w x r): the tip's acceleration relative to the IMU's, in tool coordinates,
    where the lever arm r and so these terms are fixed (they turn with the tool)."""
    return cross(alpha_tool, r_lever_tool) + cross(w_tool, cross(w_tool, r_lever_tool))


@njit(cache=True)
def propagate(
    p: np.ndarray,
    v: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    bg: np.ndarray,
    ba: np.ndarray,
    w_imu: np.ndarray,
    f_imu: np.ndarray,
    alpha_tool: np.ndarray,
    R_ti: np.ndarray,
    r_lever_tool: np.ndarray,
    q: np.ndarray,
    bg_rw_static: float,
    bg_rw_per_radps: float,
    dt: float,
    imu: bool,
    brho_per_rad: float = 0.0,
) -> None:
    """One step of dt [s], in place: p, v [base], R [base<-tool], P (16, 16). `q` holds the
    per-second process noise of each error state (the gyro-bias entries are replaced by
    (bg_rw_static + bg_rw_per_radps |w|)^2 [rad^2/s^3]; while b_rho walks, q[15] > 0, its entry
    grows by brho_per_rad |w| [m^2/rad])."""
    F_vth = np.zeros((3, 3))
    F_vba = np.zeros((3, 3))
    F_thth = np.eye(3)
    F_thbg = np.zeros((3, 3))
    qq = q.copy()
    if imu:
        w_tool = mv(R_ti, w_imu - bg)
        f_tool = mv(R_ti, f_imu - ba)
        a_tool = f_tool + lever_accel(w_tool, alpha_tool, r_lever_tool)  # the tip's, tool coordinates
        a = mv(R, a_tool)
        a[2] -= 9.80665
        wn = math.sqrt(w_tool[0] ** 2 + w_tool[1] ** 2 + w_tool[2] ** 2)
        # F_vth = -R [a_tool]x dt: the lever arm's terms turn with the tool as the specific
        # force does, not as if fixed in the base frame
        F_vth = mm(R, skew(a_tool)) * -dt
        F_vba = mm(R, R_ti) * -dt
        exp_into(-w_tool[0] * dt, -w_tool[1] * dt, -w_tool[2] * dt, F_thth)
        F_thbg = R_ti * -dt
        s = bg_rw_static + bg_rw_per_radps * wn
        qq[9] = qq[10] = qq[11] = s * s
        if qq[15] > 0.0:
            qq[15] += brho_per_rad * wn
        dR = np.empty((3, 3))
        exp_into(w_tool[0] * dt, w_tool[1] * dt, w_tool[2] * dt, dR)
        R[:, :] = mm(R, dR)
    else:
        a = np.zeros(3)
    for i in range(3):
        p[i] += v[i] * dt + 0.5 * dt * dt * a[i]
        v[i] += a[i] * dt
    # F = I + sparse blocks: rows p (p += dt v), v (v += F_vth th + F_vba ba), th (F_thth th + F_thbg bg)
    # FP = F @ P computed by rows
    FP = P.copy()
    for j in range(N):
        for i in range(3):
            acc = P[3 + i, j]
            acc2 = 0.0
            for k in range(3):
                acc += F_vth[i, k] * P[6 + k, j] + F_vba[i, k] * P[12 + k, j]
                acc2 += F_thth[i, k] * P[6 + k, j] + F_thbg[i, k] * P[9 + k, j]
            FP[i, j] = P[i, j] + 0.5 * dt * (P[3 + i, j] + acc)  # p += v dt + a dt^2 / 2
            FP[3 + i, j] = acc
            FP[6 + i, j] = acc2
    # P' = FP @ F^T by columns
    for i in range(N):
        for r_ in range(3):
            acc = FP[i, 3 + r_]
            acc2 = 0.0
            for k in range(3):
                acc += FP[i, 6 + k] * F_vth[r_, k] + FP[i, 12 + k] * F_vba[r_, k]
                acc2 += FP[i, 6 + k] * F_thth[r_, k] + FP[i, 9 + k] * F_thbg[r_, k]
            P[i, r_] = FP[i, r_] + 0.5 * dt * (FP[i, 3 + r_] + acc)
            P[i, 3 + r_] = acc
            P[i, 6 + r_] = acc2
        for c in range(9, N):
            P[i, c] = FP[i, c]
    for i in range(N):
        P[i, i] += qq[i] * dt


@njit(cache=True)
def propagate_held(
    p: np.ndarray, v: np.ndarray, R: np.ndarray, P: np.ndarray, bg: np.ndarray, ba: np.ndarray,
    w_held: np.ndarray, f_imu: np.ndarray, alpha_tool: np.ndarray, R_ti: np.ndarray, r_lever_tool: np.ndarray,
    q: np.ndarray, k: np.ndarray, dt: float, imu: bool,
) -> None:  # fmt: skip
    """`propagate` over dt with the latest samples held, k the gyro-step constants (`layout.GK_*`).
    Past k[GK_IMU_GAP_S] without an IMU sample (a stalled host) the held samples say little about
    the motion: the rest of the step is propagated as without an IMU (the velocity held, no
    rotation), and the velocity gets the uncertainty it has without an IMU, k[GK_NO_IMU_Q], for
    every further second (integrating a held specific force or rate for the whole stall ran a
    tool that was accelerating off by tens of centimetres)."""
    gap = k[GK_IMU_GAP_S]
    held = dt if not (imu and dt > gap) else gap
    propagate(
        p, v, R, P, bg, ba, w_held, f_imu, alpha_tool, R_ti, r_lever_tool, q, k[GK_BG_RW], k[GK_BG_RW_PER_RADPS], held,
        imu, k[GK_BRHO_PER_RAD],
    )  # fmt: skip
    if imu and dt > gap:
        propagate(
            p, v, R, P, bg, ba, w_held, f_imu, alpha_tool, R_ti, r_lever_tool, q, k[GK_BG_RW], k[GK_BG_RW_PER_RADPS],
            dt - gap, False, k[GK_BRHO_PER_RAD],
        )  # fmt: skip
        for i in range(3, 6):
            P[i, i] += k[GK_NO_IMU_Q] * (dt - gap)


@njit(cache=True)
def transition(
    R: np.ndarray, bg: np.ndarray, ba: np.ndarray, w_imu: np.ndarray, f_imu: np.ndarray, alpha_tool: np.ndarray,
    R_ti: np.ndarray, r_lever_tool: np.ndarray, dt: float, imu: bool,
) -> np.ndarray:  # fmt: skip
    """The error-state transition F (16, 16) that `propagate` applies for a step of dt [s]."""
    F = np.eye(N)
    for i in range(3):
        F[i, 3 + i] = dt
    if imu:
        w_tool = R_ti @ (w_imu - bg)
        a_tool = R_ti @ (f_imu - ba) + lever_accel(w_tool, alpha_tool, r_lever_tool)
        F[3:6, 6:9] = -(R @ skew(a_tool)) * dt
        F[3:6, 12:15] = -(R @ R_ti) * dt
        F[0:3, 6:9] = F[3:6, 6:9] * (0.5 * dt)
        F[0:3, 12:15] = F[3:6, 12:15] * (0.5 * dt)
        E = np.empty((3, 3))
        exp_into(-w_tool[0] * dt, -w_tool[1] * dt, -w_tool[2] * dt, E)
        F[6:9, 6:9] = E
        F[6:9, 9:12] = -R_ti * dt
    return F
