"""What one IMU sample does, in one compiled call each: called piece by piece from Python, the
calls' overhead would be about half the filter's time. `gyro_step`: propagation, the angular
acceleration, the RCM update, the state's health and the rest detector; `gravity_step`: the
rest detector, propagation and the gravity update."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import mv
from services.fusion.eskf.kernels.propagate import propagate_held
from services.fusion.eskf.kernels.rest import rest_sample
from services.fusion.eskf.kernels.update import gain_hi, health, inject, update
from services.fusion.eskf.layout import (
    GK_MAX_POS_VAR,
    GK_MAX_SPEED2,
    GK_RCM_CHI2,
    GK_RCM_VAR,
    GR_CHI2,
    GR_SIGMA,
    GR_SIGMA_PER_EXCESS,
)
from services.fusion.eskf.models.gravity import gravity_jacobian
from services.fusion.eskf.models.rcm import port_lever, rcm_jacobian


@njit(cache=True)
def gyro_step(
    p: np.ndarray, v: np.ndarray, R: np.ndarray, P: np.ndarray, bg: np.ndarray, ba: np.ndarray,
    w_held: np.ndarray, f_imu: np.ndarray, alpha_tool: np.ndarray, R_ti: np.ndarray, r_lever_tool: np.ndarray,
    q: np.ndarray, k: np.ndarray, dt: float, imu: bool, w_new: np.ndarray, w_old: np.ndarray, dt_alpha: float,
    rcm: np.ndarray, do_rcm: bool, freeze_last: bool, rest: np.ndarray, t_s: float, rest_k: np.ndarray,
) -> tuple[int, float, float, int, bool]:  # fmt: skip
    """Everything one gyro sample does, in one call (called per step from Python, the overhead
    would be about half the filter's time): `propagate_held` over dt with the held samples (w_held, f_imu, alpha_tool);
    the angular acceleration alpha_tool = R_ti (w_new - w_old) / dt_alpha (zero when dt_alpha is 0,
    unchanged when negative); then, if do_rcm, the RCM update (variance k[GK_RCM_VAR] per axis,
    gate k[GK_RCM_CHI2]); then the state's `health`; last, with the IMU, w_new at t_s [s] through
    the rest detector (`rest_sample`, rest_k; an empty rest_k: none). k holds the gyro-step
    constants (`layout.GK_*`). Returns (status, NIS, b_rho increment, health, whether the rest detector
    released a chunk), status -1 when no RCM update was made, else as `update`."""
    if dt > 0.0:
        propagate_held(p, v, R, P, bg, ba, w_held, f_imu, alpha_tool, R_ti, r_lever_tool, q, k, dt, imu)
    if imu and dt_alpha >= 0.0:
        if dt_alpha > 0.0:
            a = mv(R_ti, (w_new - w_old) / dt_alpha)
            for i in range(3):
                alpha_tool[i] = a[i]
        else:
            for i in range(3):
                alpha_tool[i] = 0.0
    status, nis, dbrho = -1, 0.0, 0.0
    if do_rcm:
        H, y = rcm_jacobian(R, p, rcm)
        r_var = np.empty(2)
        r_var[0] = r_var[1] = k[GK_RCM_VAR]
        status, nis, dx = update(P, H, y, r_var, k[GK_RCM_CHI2], 0, gain_hi(freeze_last))
        if status == 0:
            dbrho = inject(p, v, R, bg, ba, dx, P)
    hl = health(p, v, R, P, k[GK_MAX_POS_VAR], k[GK_MAX_SPEED2])
    released = imu and rest_k.shape[0] > 0 and rest_sample(rest, w_new, t_s, 0, rest_k)
    return status, nis, dbrho, hl, released


@njit(cache=True)
def gravity_step(
    p: np.ndarray, v: np.ndarray, R: np.ndarray, P: np.ndarray, bg: np.ndarray, ba: np.ndarray,
    w_held: np.ndarray, f_imu: np.ndarray, alpha_tool: np.ndarray, R_ti: np.ndarray, r_lever_tool: np.ndarray,
    q: np.ndarray, k: np.ndarray, dt: float, g: np.ndarray, freeze_last: bool, rcm: np.ndarray,
    acc: np.ndarray, f_corr: np.ndarray, max_excess: float, rest: np.ndarray, t_s: float, rest_k: np.ndarray,
) -> tuple[int, float, float, bool]:  # fmt: skip
    """What an accelerometer sample due for a gravity update does, in one call (it comes at
    every sample): `propagate_held` over dt (k as in `gyro_step`; 0 when the caller propagated
    already), then the gravity update (`gravity_jacobian`, the shaft's point at the port `rcm`
    taken at rest: `port_lever`) with the standard deviation g[GR_SIGMA] + g[GR_SIGMA_PER_EXCESS]
    | |f|/g - 1 | [rad] of the direction per axis and chi-square gate g[GR_CHI2]. Returns (status, NIS, b_rho increment,
    recorded), status as `update`.

    With max_excess >= 0 an applied update whose |f| is within max_excess of g is also
    recorded for the accelerometer's pose map: acc (16,) sums the pose before the update
    (R [0:9] row-major, p [9:12]) and the residual against the reading before the map's
    correction f_corr was taken off it [12:15], and counts it [15].

    First of all, f_imu at t_s [s] goes through the rest detector (`rest_sample`, rest_k; an
    empty rest_k: none)."""
    if rest_k.shape[0] > 0:
        rest_sample(rest, f_imu, t_s, 1, rest_k)
    if dt > 0.0:
        propagate_held(p, v, R, P, bg, ba, w_held, f_imu, alpha_tool, R_ti, r_lever_tool, q, k, dt, True)
    H, y = gravity_jacobian(R, R_ti, port_lever(R, p, rcm, r_lever_tool), w_held, bg, ba, alpha_tool, f_imu)
    fn = math.sqrt(f_imu[0] * f_imu[0] + f_imu[1] * f_imu[1] + f_imu[2] * f_imu[2])
    excess = abs(fn / 9.80665 - 1.0)
    record = max_excess >= 0.0 and excess <= max_excess
    if record:
        for i in range(3):
            for j in range(3):
                acc[3 * i + j] += R[i, j]
            acc[9 + i] += p[i]
    sig = (g[GR_SIGMA] + g[GR_SIGMA_PER_EXCESS] * excess) * 9.80665
    r_var = np.empty(3)
    r_var[0] = r_var[1] = r_var[2] = sig * sig
    status, nis, dx = update(P, H, y, r_var, g[GR_CHI2], 0, gain_hi(freeze_last))
    dbrho = 0.0
    if status == 0:
        dbrho = inject(p, v, R, bg, ba, dx, P)
        if record:
            for i in range(3):
                acc[12 + i] += y[i] + f_corr[i]
            acc[15] += 1.0
    elif record:  # not applied: the pose comes off again
        for i in range(3):
            for j in range(3):
                acc[3 * i + j] -= R[i, j]
            acc[9 + i] -= p[i]
        record = False
    return status, nis, dbrho, record
