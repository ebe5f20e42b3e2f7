"""The filter's hot loops compiled with numba: one propagation step (nominal state and
covariance), one Kalman update, and everything a gyro sample does in one call (`gyro_step`).
Pure numpy could not reach the offline speed target (a 120 s block in 2.4 s on one core, with
every late vision frame re-propagated): each step is a handful of 16x16 products that numpy
dispatches one call at a time. Small products are written out: numba would hand them to BLAS
and LAPACK, whose calls cost more than the arithmetic at 3x3 and m <= 4. numba is a dependency
of tiplog; `NUMBA_DISABLE_JIT=1` runs the same functions as plain Python (slow, same results).
The tests check both against plain numpy (F P F^T + Q, the textbook update).

Layout of the error state: [dp 0:3, dv 3:6, dtheta 6:9, db_g 9:12, db_a 12:15, db_rho 15].
"""

from __future__ import annotations

import math

import numpy as np

try:  # a dependency; the fallback keeps the module importable where numba cannot be installed
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent

    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f


from services.fusion.eskf import layout as _layout
from services.fusion.eskf import so3 as _so3
from services.fusion.eskf.jit_cache import drop_stale_for
from services.fusion.eskf.layout import (
    GK_BG_RW,
    GK_BG_RW_PER_RADPS,
    GK_BRHO_PER_RAD,
    GK_IMU_GAP_S,
    GK_MAX_POS_VAR,
    GK_MAX_SPEED2,
    GK_NO_IMU_Q,
    GK_RCM_CHI2,
    GK_RCM_VAR,
    GR_CHI2,
    GR_SIGMA,
    GR_SIGMA_PER_EXCESS,
    REST_CHUNK_T0,
    REST_COUNT,
    REST_HAVE_PREV,
    REST_LP,
    REST_PREV_ACCEL,
    REST_PREV_GYRO,
    REST_RATE,
    REST_SINCE,
    REST_SIZE,
    REST_SUM,
    REST_T_LAST,
    RK_AGREE_ACCEL2,
    RK_AGREE_GYRO2,
    RK_CHUNK_S,
    RK_GAP_S,
    RK_MIN_S,
    RK_TAU_S,
    RK_TH_GYRO2,
    N,
)
from services.fusion.eskf.so3 import cross, exp_into, skew


@njit(cache=True)
def _lever_accel(w_tool: np.ndarray, alpha_tool: np.ndarray, r_lever_tool: np.ndarray) -> np.ndarray:
    """alpha x r + w x (w x r): the tip's acceleration relative to the IMU's, in tool coordinates,
    where the lever arm r and so these terms are fixed (they turn with the tool)."""
    return cross(alpha_tool, r_lever_tool) + cross(w_tool, cross(w_tool, r_lever_tool))


@njit(cache=True)
def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A (3, 3) @ x (3,) written out: numba hands `@` to BLAS, whose call costs more than the
    product at this size."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]
    return out


@njit(cache=True)
def _mtv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A.T (3, 3) @ x (3,) written out."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[0, i] * x[0] + A[1, i] * x[1] + A[2, i] * x[2]
    return out


@njit(cache=True)
def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A (3, 3) @ B (3, 3) written out."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


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
        w_tool = _mv(R_ti, w_imu - bg)
        f_tool = _mv(R_ti, f_imu - ba)
        a_tool = f_tool + _lever_accel(w_tool, alpha_tool, r_lever_tool)  # the tip's, tool coordinates
        a = _mv(R, a_tool)
        a[2] -= 9.80665
        wn = math.sqrt(w_tool[0] ** 2 + w_tool[1] ** 2 + w_tool[2] ** 2)
        # F_vth = -R [a_tool]x dt: the lever arm's terms turn with the tool as the specific
        # force does, not as if fixed in the base frame
        F_vth = _mm(R, skew(a_tool)) * -dt
        F_vba = _mm(R, R_ti) * -dt
        exp_into(-w_tool[0] * dt, -w_tool[1] * dt, -w_tool[2] * dt, F_thth)
        F_thbg = R_ti * -dt
        s = bg_rw_static + bg_rw_per_radps * wn
        qq[9] = qq[10] = qq[11] = s * s
        if qq[15] > 0.0:
            qq[15] += brho_per_rad * wn
        dR = np.empty((3, 3))
        exp_into(w_tool[0] * dt, w_tool[1] * dt, w_tool[2] * dt, dR)
        R[:, :] = _mm(R, dR)
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
def _matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A (n, k) @ B (k, m) written out, for the update's thin products (m <= 4)."""
    n, k, m = A.shape[0], A.shape[1], B.shape[1]
    out = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for c in range(k):
                acc += A[i, c] * B[c, j]
            out[i, j] = acc
    return out


@njit(cache=True)
def gain_hi(freeze_last: bool) -> int:
    """`update`'s hi: every error state, or all but the last (b_rho, held)."""
    return N - 1 if freeze_last else N


@njit(cache=True)
def update(
    P: np.ndarray, H: np.ndarray, y: np.ndarray, r_var: np.ndarray, chi2: float, lo: int, hi: int
) -> tuple[int, float, np.ndarray]:
    """Kalman update of P (16, 16) in place with H (m, 16), innovation y (m,), measurement
    variances r_var (m,). Returns (status, NIS, dx): status 0 applied, 1 rejected by the
    chi-square gate (or an innovation covariance that is not positive definite). Only the
    error states lo..hi-1 get gain (a Schmidt update: `gain_hi(freeze_last)` leaves out b_rho
    while it is held; the rest without vision moves the gyro bias alone); with any left out, P
    follows the Joseph form for that gain, expanded: P - K H P - P H^T K^T + K S K^T. Written
    out in loops (S by Cholesky): at m <= 4 the BLAS and LAPACK calls cost more than the
    arithmetic."""
    m = y.shape[0]
    PHt = np.zeros((N, m))
    for a in range(m):
        for j in range(N):
            h = H[a, j]
            if h != 0.0:
                for i in range(N):
                    PHt[i, a] += P[i, j] * h
    S = _matmul(H, PHt)
    for a in range(m):
        S[a, a] += r_var[a]
    # Cholesky S = L L^T (S symmetrised by reading its lower triangle)
    L = np.zeros((m, m))
    for a in range(m):
        for b in range(a + 1):
            acc = 0.5 * (S[a, b] + S[b, a])
            for c in range(b):
                acc -= L[a, c] * L[b, c]
            if a == b:
                if not acc > 0.0:
                    return 1, math.inf, np.zeros(N)
                L[a, a] = math.sqrt(acc)
            else:
                L[a, b] = acc / L[b, b]
    # Sinv = L^-T L^-1 from the inverse of L
    Li = np.zeros((m, m))
    for a in range(m):
        Li[a, a] = 1.0 / L[a, a]
        for b in range(a):
            acc = 0.0
            for c in range(b, a):
                acc -= L[a, c] * Li[c, b]
            Li[a, b] = acc / L[a, a]
    Sinv = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for c in range(max(a, b), m):
                acc += Li[c, a] * Li[c, b]
            Sinv[a, b] = acc
    nis = 0.0
    for a in range(m):
        for b in range(m):
            nis += y[a] * Sinv[a, b] * y[b]
    if not nis <= chi2:
        return 1, nis, np.zeros(N)
    K = _matmul(PHt, Sinv)
    if lo > 0 or hi < N:
        for i in range(N):
            if i < lo or i >= hi:
                for b in range(m):
                    K[i, b] = 0.0
        KS = _matmul(K, S)
        for i in range(N):
            for j in range(i, N):
                acc = 0.0
                for a in range(m):
                    acc += KS[i, a] * K[j, a] - K[i, a] * PHt[j, a] - PHt[i, a] * K[j, a]
                v = 0.5 * (P[i, j] + P[j, i]) + acc
                P[i, j] = v
                P[j, i] = v
    else:
        for i in range(N):
            for j in range(i, N):
                a1 = 0.0
                a2 = 0.0
                for a in range(m):
                    a1 += K[i, a] * PHt[j, a]
                    a2 += K[j, a] * PHt[i, a]
                v = 0.5 * ((P[i, j] - a1) + (P[j, i] - a2))
                P[i, j] = v
                P[j, i] = v
    dx = np.zeros(N)
    for i in range(N):
        acc = 0.0
        for a in range(m):
            acc += K[i, a] * y[a]
        dx[i] = acc
    return 0, nis, dx


@njit(cache=True)
def inject(
    p: np.ndarray, v: np.ndarray, R: np.ndarray, bg: np.ndarray, ba: np.ndarray, dx: np.ndarray, P: np.ndarray
) -> float:
    """Error state dx (16,) into the nominal state, in place; returns the b_rho increment.
    P is carried to the new estimate as the covariance of the invariant error (`reset`)."""
    R0 = R.copy()
    dR = np.empty((3, 3))
    exp_into(dx[6], dx[7], dx[8], dR)
    R[:, :] = _mm(R, dR)
    for i in range(3):
        p[i] += dx[i]
        v[i] += dx[3 + i]
        bg[i] += dx[9 + i]
        ba[i] += dx[12 + i]
    reset(P, R0, dR, dx[0:3], dx[3:6])
    return dx[15]


@njit(cache=True)
def reset(P: np.ndarray, R0: np.ndarray, dR: np.ndarray, step_p: np.ndarray, step_v: np.ndarray) -> None:
    """P (16, 16), in place, from the estimate (p, v, R0) to (p + step_p, v + step_v, R0 dR).

    The filter's covariance is that of the right-invariant error (world-frame rotation xi_R,
    p - xi_R x (p - r), v - xi_R x v about the RCM r): local coordinates serve the Jacobians,
    dp = xi_p + xi_R x q, dv = xi_v + xi_R x v, dtheta = R^T xi_R. A rotation of the whole
    state about the vertical through the RCM (heading, which only vision and the ToF observe)
    is then one fixed direction of the error whatever the estimate, so the RCM and gravity
    updates, whose Jacobians are blind to it at their own estimate, can never feed it
    information. Keeping the same P across a change of estimate in local coordinates would
    (each update turns that direction a little; over minutes without vision the heading sigma
    settled at 1 deg while the heading walked off by tens). The change of coordinates
    G = T(new) T(old)^-1 is the identity but for dtheta' = dR^T dtheta,
    dp' = dp - [step_p]x R0 dtheta, dv' = dv - [step_v]x R0 dtheta: P <- G P G^T."""
    M = np.empty((9, 3))  # G's dtheta columns: -[step_p]x R0, -[step_v]x R0, dR^T
    M[0:3] = -_mm(skew(step_p), R0)
    M[3:6] = -_mm(skew(step_v), R0)
    M[6:9] = dR.T
    # rows: GP[i] = P[i] + M[i] P[6:9] (i < 6), GP[6 + i] = M[6 + i] P[6:9]
    Pt = P[6:9, :].copy()
    for i in range(9):
        for j in range(N):
            acc = M[i, 0] * Pt[0, j] + M[i, 1] * Pt[1, j] + M[i, 2] * Pt[2, j]
            if i < 6:
                P[i, j] += acc
            else:
                P[i, j] = acc
    # columns, the same on (G P) G^T
    Pc = P[:, 6:9].copy()
    for j in range(9):
        for i in range(N):
            acc = Pc[i, 0] * M[j, 0] + Pc[i, 1] * M[j, 1] + Pc[i, 2] * M[j, 2]
            if j < 6:
                P[i, j] += acc
            else:
                P[i, j] = acc


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
            a = _mv(R_ti, (w_new - w_old) / dt_alpha)
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


@njit(cache=True)
def kernel_mean(
    K: np.ndarray, k2: np.ndarray, E: np.ndarray, T: np.ndarray, n: int, t_lo: int, R: np.ndarray, p: np.ndarray,
    wk: np.ndarray, out: np.ndarray,
) -> float:  # fmt: skip
    """The pose maps' query (`maps`): of the entries 0:n with keys K (., 12), their
    weighted square norms k2, values E (., d) and times T (ascending), those at or after t_lo,
    weighted w_i = exp(-|K_i - q|^2_W / 2) with q the pose (R, p) as a key and W = diag(wk);
    writes sum_i w_i E_i to out (d,) and returns sum_i w_i. Entries past 12 kernel widths (a
    weight under 1e-31) are skipped."""
    d = E.shape[1]
    for c in range(d):
        out[c] = 0.0
    lo, hi = 0, n  # the first entry at or after t_lo
    while lo < hi:
        mid = (lo + hi) // 2
        if T[mid] < t_lo:
            lo = mid + 1
        else:
            hi = mid
    qw = np.empty(12)
    qq = 0.0
    for i in range(3):
        for j in range(3):
            qw[3 * i + j] = wk[3 * i + j] * R[i, j]
            qq += qw[3 * i + j] * R[i, j]
        qw[9 + i] = wk[9 + i] * p[i]
        qq += qw[9 + i] * p[i]
    sw = 0.0
    for i in range(lo, n):
        dot = 0.0
        for c in range(12):
            dot += K[i, c] * qw[c]
        d2 = k2[i] - 2.0 * dot + qq
        if d2 < 144.0:
            w = math.exp(-0.5 * max(d2, 0.0))
            sw += w
            for c in range(d):
                out[c] += w * E[i, c]
    return sw


@njit(cache=True)
def finite(p: np.ndarray, R: np.ndarray, P: np.ndarray) -> bool:
    """Whether a state is finite: a NaN anywhere reaches the position block of P within one step."""
    return math.isfinite(p[0] + p[1] + p[2] + R[0, 0] + P[0, 0] + P[2, 2])


@njit(cache=True)
def health(p: np.ndarray, v: np.ndarray, R: np.ndarray, P: np.ndarray, max_pos_var: float, max_speed2: float) -> int:
    """0 for a sound state; 1 when not `finite`, 2 when the tip's variance (trace of the
    position block) exceeds max_pos_var [m^2], 3 when the speed squared exceeds max_speed2
    [m^2/s^2]."""
    if not finite(p, R, P):
        return 1
    if P[0, 0] + P[1, 1] + P[2, 2] > max_pos_var:
        return 2
    if v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > max_speed2:
        return 3
    return 0


def rest_init() -> np.ndarray:
    """A rest detector's state (`State.rest`, slots `layout.REST_*`): no sample yet."""
    r = np.zeros(REST_SIZE)
    r[REST_T_LAST : REST_T_LAST + 2] = np.nan
    r[REST_SINCE] = np.nan
    return r


@njit(cache=True)
def _rest_break(rest: np.ndarray) -> None:
    rest[REST_SINCE] = np.nan
    rest[REST_COUNT] = rest[REST_COUNT + 1] = 0.0
    rest[REST_HAVE_PREV] = 0.0


@njit(cache=True)
def rest_sample(rest: np.ndarray, x: np.ndarray, t_s: float, accel: int, k: np.ndarray) -> bool:
    """One gyro (accel=0, x in rad/s) or accelerometer (accel=1, m/s^2) sample through the rest
    detector (state `rest`, constants k: `layout.REST_*`, `layout.RK_*`). First VQF's test: every
    sample of both near its channel's low-pass for k[RK_MIN_S]; a gap over k[RK_GAP_S] restarts
    the channel. Then the samples are averaged in chunks of k[RK_CHUNK_S], and a chunk is taken
    for rest only when the next one agrees with it: a slow smooth motion stays near its
    low-pass, but its mean rate or its gravity moves from chunk to chunk. A chunk's mean rate is
    then released into rest[REST_RATE:] (True returned); any sample off its low-pass drops the
    chunks not yet released, so none from a motion's onset is used."""
    lp, it = REST_LP + 3 * accel, REST_T_LAST + accel
    t_last = rest[it]
    rest[it] = t_s
    if not t_s - t_last <= k[RK_GAP_S]:  # the channel's first sample (NaN), or after a gap
        for i in range(3):
            rest[lp + i] = x[i]
        _rest_break(rest)
        return False
    a = 1.0 - math.exp(-(t_s - t_last) / k[RK_TAU_S])
    d2 = 0.0
    for i in range(3):
        rest[lp + i] += a * (x[i] - rest[lp + i])
        e = x[i] - rest[lp + i]
        d2 += e * e
    if d2 >= k[RK_TH_GYRO2 + accel]:  # RK_TH_ACCEL2 follows RK_TH_GYRO2
        _rest_break(rest)
        return False
    if math.isnan(rest[REST_SINCE]):
        rest[REST_SINCE] = t_s
        return False
    if t_s - rest[REST_SINCE] < k[RK_MIN_S]:
        return False
    if rest[REST_COUNT] + rest[REST_COUNT + 1] == 0.0:
        rest[REST_CHUNK_T0] = t_s
        for i in range(REST_SUM, REST_SUM + 6):
            rest[i] = 0.0
    for i in range(3):
        rest[REST_SUM + 3 * accel + i] += x[i]
    rest[REST_COUNT + accel] += 1.0
    if accel or t_s - rest[REST_CHUNK_T0] < k[RK_CHUNK_S] or rest[REST_COUNT + 1] == 0.0:
        return False
    g = np.empty(3)
    f = np.empty(3)
    dg = df = 0.0
    for i in range(3):
        g[i] = rest[REST_SUM + i] / rest[REST_COUNT]
        f[i] = rest[REST_SUM + 3 + i] / rest[REST_COUNT + 1]
        dg += (g[i] - rest[REST_PREV_GYRO + i]) ** 2
        df += (f[i] - rest[REST_PREV_ACCEL + i]) ** 2
    ready = rest[REST_HAVE_PREV] > 0.0 and dg < k[RK_AGREE_GYRO2] and df < k[RK_AGREE_ACCEL2]
    for i in range(3):
        rest[REST_RATE + i] = rest[REST_PREV_GYRO + i]
        rest[REST_PREV_GYRO + i] = g[i]
        rest[REST_PREV_ACCEL + i] = f[i]
    # a disagreeing pair: neither is rest
    rest[REST_HAVE_PREV] = 1.0 if rest[REST_HAVE_PREV] == 0.0 or ready else 0.0
    rest[REST_COUNT] = rest[REST_COUNT + 1] = 0.0
    return ready


@njit(cache=True)
def rcm_jacobian(R: np.ndarray, p: np.ndarray, rcm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H (2, 16), y (2,)) of the RCM pseudo-measurement (R^T (r - p))_xy = 0."""
    d = _mtv(R, rcm - p)
    H = np.zeros((2, N))
    for i in range(2):
        for j in range(3):
            H[i, j] = -R[j, i]
    # rows x, y of skew(d)
    H[0, 7], H[0, 8] = -d[2], d[1]
    H[1, 6], H[1, 8] = d[2], -d[0]
    y = np.empty(2)
    y[0], y[1] = -d[0], -d[1]
    return H, y


@njit(cache=True)
def port_lever(R: np.ndarray, p: np.ndarray, rcm: np.ndarray, r_lever_tool: np.ndarray) -> np.ndarray:
    """The lever arm from the IMU to the shaft's point at the port, in tool coordinates:
    r_lever_tool (IMU to tip) less the insertion depth L = u.(p - rcm) along the shaft axis.
    Through a trocar that point, not the tip, is the one at rest while the tool pivots (the
    tip swings by L alpha, 0.8 m/s^2 at the sweeps' fastest); only sliding along the shaft
    moves it. The update's Jacobian leaves out the lever's dependence on the depth: a depth
    off by 1 mm moves the prediction by (|alpha| + |w|^2) mm/s^2, 0.04 deg of gravity there."""
    L = R[0, 2] * (p[0] - rcm[0]) + R[1, 2] * (p[1] - rcm[1]) + R[2, 2] * (p[2] - rcm[2])
    out = r_lever_tool.copy()
    out[2] -= L
    return out


@njit(cache=True)
def gravity_jacobian(
    R: np.ndarray, R_ti: np.ndarray, r_lever_tool: np.ndarray, w_imu: np.ndarray,
    bg: np.ndarray, ba: np.ndarray, alpha_tool: np.ndarray, f_imu: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(H (3, 16), y (3,)) of the gravity update: the specific force at the IMU predicted as
    gravity plus the lever arm's tangential and centripetal terms (the lever's far end at rest:
    `gravity_step` passes the shaft's point at the port, `port_lever`),
    f = R_ti^T R^T (a_imu - g) + b_a. The lever-arm terms turn with the tool (they are fixed in
    tool coordinates), so only gravity's share depends on the attitude error: H_theta =
    R_ti^T [R^T (-g)]x."""
    w_t = _mv(R_ti, w_imu - bg)
    a_t = -_lever_accel(w_t, alpha_tool, r_lever_tool)  # the IMU's acceleration (far end at rest), tool coordinates
    w = np.empty(3)  # R^T (-g): gravity's share, in tool coordinates
    for i in range(3):
        w[i] = 9.80665 * R[2, i]
    f_pred = _mtv(R_ti, a_t + w) + ba
    H = np.zeros((3, N))
    # R_ti^T skew(w)
    for i in range(3):
        H[i, 6] = R_ti[1, i] * w[2] - R_ti[2, i] * w[1]
        H[i, 7] = R_ti[2, i] * w[0] - R_ti[0, i] * w[2]
        H[i, 8] = R_ti[0, i] * w[1] - R_ti[1, i] * w[0]
        H[i, 12 + i] = 1.0
    return H, f_imu - f_pred


@njit(cache=True)
def tof_jacobian(
    R: np.ndarray, p: np.ndarray, brho: float, m: np.ndarray, h: float, o: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """(H (1, 16), predicted range [m], m.(R b)) of rho = (h - m.(p + R o)) / (m.(R b)) + b_rho."""
    Ro = _mv(R, o)
    Rb = _mv(R, b)
    den = m[0] * Rb[0] + m[1] * Rb[1] + m[2] * Rb[2]
    H = np.zeros((1, N))
    if den < 1e-9:
        return H, 0.0, den
    num = h - (m[0] * (p[0] + Ro[0]) + m[1] * (p[1] + Ro[1]) + m[2] * (p[2] + Ro[2]))
    mR = _mtv(R, m)
    # mR @ skew(o) and mR @ skew(b)
    so = np.array([mR[1] * o[2] - mR[2] * o[1], mR[2] * o[0] - mR[0] * o[2], mR[0] * o[1] - mR[1] * o[0]])
    sb = np.array([mR[1] * b[2] - mR[2] * b[1], mR[2] * b[0] - mR[0] * b[2], mR[0] * b[1] - mR[1] * b[0]])
    k = num / (den * den)
    for j in range(3):
        H[0, j] = -m[j] / den
        H[0, 6 + j] = so[j] / den + k * sb[j]
    H[0, 15] = 1.0
    return H, num / den + brho, den


@njit(cache=True)
def sample_fields(R: np.ndarray, p: np.ndarray, P: np.ndarray, rcm: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(qw, qx, qy, qz, depth [m], tilt [deg], roll [deg], sigma_x, sigma_y, sigma_z [m],
    attitude sigma [deg]) of a state: Shepperd's quaternion (w >= 0), depth along the shaft
    from the RCM, tilt from `neutral`, roll of tool x about the shaft from the horizontal, the
    tip's 1-sigma along the base axes and the root of the attitude covariance's trace."""
    out = np.empty(11)
    for i in range(3):
        out[7 + i] = math.sqrt(max(P[i, i], 0.0))
    out[10] = math.degrees(math.sqrt(max(P[6, 6] + P[7, 7] + P[8, 8], 0.0)))
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    elif m00 > m11 and m00 > m22:
        s = math.sqrt(1.0 + m00 - m11 - m22) * 2
        q = ((R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s)
    elif m11 > m22:
        s = math.sqrt(1.0 + m11 - m00 - m22) * 2
        q = ((R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + m22 - m00 - m11) * 2
        q = ((R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s)
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sg = -1.0 if q[0] < 0 else 1.0
    for i in range(4):
        out[i] = sg * q[i] / n
    u0, u1, u2 = R[0, 2], R[1, 2], R[2, 2]
    out[4] = (p[0] - rcm[0]) * u0 + (p[1] - rcm[1]) * u1 + (p[2] - rcm[2]) * u2
    c = min(1.0, max(-1.0, u0 * neutral[0] + u1 * neutral[1] + u2 * neutral[2]))
    out[5] = math.degrees(math.acos(c))
    hx, hy = -u1, u0  # e_z x u
    hn = math.sqrt(hx * hx + hy * hy)
    out[6] = 0.0
    if hn > 1e-9:
        hx /= hn
        hy /= hn
        x0, x1, x2 = R[0, 0], R[1, 0], R[2, 0]
        # (h x x) . u and h . x
        cx = hy * x2
        cy = -hx * x2
        cz = hx * x1 - hy * x0
        out[6] = math.degrees(math.atan2(cx * u0 + cy * u1 + cz * u2, hx * x0 + hy * x1))
    return out


@njit(cache=True)
def shaft_depth(R: np.ndarray, p: np.ndarray, rcm: np.ndarray) -> float:
    """The tip's depth along the shaft R[:, 2] from the RCM, u . (p - rcm) [m] (numpy's
    `u @ (p - rcm)` to the bit, in one call instead of three array operations)."""
    return R[0, 2] * (p[0] - rcm[0]) + R[1, 2] * (p[1] - rcm[1]) + R[2, 2] * (p[2] - rcm[2])


@njit(cache=True)
def sample_row(
    R: np.ndarray, p: np.ndarray, v: np.ndarray, P: np.ndarray, bg: np.ndarray, ba: np.ndarray, rcm: np.ndarray,
    neutral: np.ndarray, only_finite: bool,
) -> np.ndarray:  # fmt: skip
    """A published sample's arrays in one (26,) row, so that it is made in one call: p [0:3],
    v [3:6], the quaternion [6:10], the shaft direction R[:, 2] [10:13], bg [13:16], ba [16:19],
    the tip's 1-sigma [19:22], then depth, tilt, roll and the attitude sigma [22:26]
    (`sample_fields`). With only_finite, an empty row for a state that is not `finite`."""
    if only_finite and not finite(p, R, P):
        return np.empty(0)
    f = sample_fields(R, p, P, rcm, neutral)
    out = np.empty(26)
    for i in range(3):
        out[i] = p[i]
        out[3 + i] = v[i]
        out[10 + i] = R[i, 2]
        out[13 + i] = bg[i]
        out[16 + i] = ba[i]
        out[19 + i] = f[7 + i]
    for i in range(4):
        out[6 + i] = f[i]
    for i in range(3):
        out[22 + i] = f[4 + i]
    out[25] = f[10]
    return out


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
        a_tool = R_ti @ (f_imu - ba) + _lever_accel(w_tool, alpha_tool, r_lever_tool)
        F[3:6, 6:9] = -(R @ skew(a_tool)) * dt
        F[3:6, 12:15] = -(R @ R_ti) * dt
        F[0:3, 6:9] = F[3:6, 6:9] * (0.5 * dt)
        F[0:3, 12:15] = F[3:6, 12:15] * (0.5 * dt)
        E = np.empty((3, 3))
        exp_into(-w_tool[0] * dt, -w_tool[1] * dt, -w_tool[2] * dt, E)
        F[6:9, 6:9] = E
        F[6:9, 9:12] = -R_ti * dt
    return F


# numba keys this module's cache on this file alone: so3.py's functions and layout.py's
# constants are compiled in too, so an edit of either drops the cached kernels (jit_cache.py)
drop_stale_for(gyro_step, [_so3.__file__, _layout.__file__])
