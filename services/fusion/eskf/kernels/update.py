"""The Kalman update written out for the filter's small measurements (m <= 4: S by Cholesky,
BLAS and LAPACK would cost more than the arithmetic), the error's injection into the nominal
state with the covariance carried to the new estimate (`reset`), and the state's checks."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import matmul, mm
from services.fusion.eskf.kernels.so3 import exp_into, skew
from services.fusion.eskf.layout import N


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
    S = matmul(H, PHt)
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
    K = matmul(PHt, Sinv)
    if lo > 0 or hi < N:
        for i in range(N):
            if i < lo or i >= hi:
                for b in range(m):
                    K[i, b] = 0.0
        KS = matmul(K, S)
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
    R[:, :] = mm(R, dR)
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
    M[0:3] = -mm(skew(step_p), R0)
    M[3:6] = -mm(skew(step_v), R0)
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
