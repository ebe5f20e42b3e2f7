"""Offline six-axis attitude: the whole recording at once, each sample's orientation from the
samples before and after it. Pure numpy (numba-compiled loops), no I/O.

Follows offline VQF's structure (Laidig and Seel 2023, section 3.4):

- the online filter (`attitude.AttitudeFilter`) runs forward and, on the time-reversed
  recording, backward; the two gyroscope bias estimates are combined row by row, each
  weighted by the inverse of its covariance;
- the gyroscope, less that bias, is integrated over the whole recording;
- the accelerometer, rotated into that integrated frame, is low-passed forward and backward
  (the online filter's second-order low-pass, time constant `tau_acc_s`, so no phase lag);
- each sample's inclination correction turns its low-passed vector onto +z.

Unlike offline VQF, every step uses its own time step, a gap longer than `max_gap_s` splits
the recording into pieces solved apart, missing (NaN) values are skipped, and a gyroscope
delay (`gyr_delay_s`) is undone by moving the gyroscope's samples back onto the stamps
(linear interpolation) instead of carrying the orientation forward.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from services.fusion.attitude.filter import (
    AttitudeFilter,
    Params,
    input_rows,
    jit,
    lowpass,
    lowpass_coeffs,
)
from services.fusion.eskf.kernels.so3 import quat_matrix, quat_mul


@jit
def _integrate(t_s: np.ndarray, rate_radps: np.ndarray, acc: np.ndarray, q_out: np.ndarray, acc_i: np.ndarray) -> None:
    """Strapdown of rate (N, 3) [rad/s, bias removed, no NaN] from identity -> q_out (N, 4),
    each row's sample the mean rate over the step that ends at its stamp (as online); acc
    (N, 3) rotated into that frame -> acc_i (N, 3) (NaN stays NaN)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    dq = np.empty(4)
    R = np.empty(9)
    for i in range(t_s.shape[0]):
        if i > 0:
            dt = t_s[i] - t_s[i - 1]
            ex = rate_radps[i, 0] * dt
            ey = rate_radps[i, 1] * dt
            ez = rate_radps[i, 2] * dt
            ang = math.sqrt(ex * ex + ey * ey + ez * ez)
            if ang > 1e-15:
                s = math.sin(0.5 * ang) / ang
                dq[0], dq[1], dq[2], dq[3] = math.cos(0.5 * ang), s * ex, s * ey, s * ez
                quat_mul(q, dq, q)
        for k in range(4):
            q_out[i, k] = q[k]
        quat_matrix(q, R)
        for k in range(3):
            acc_i[i, k] = R[3 * k] * acc[i, 0] + R[3 * k + 1] * acc[i, 1] + R[3 * k + 2] * acc[i, 2]


def strapdown(t_s: np.ndarray, rate_radps: np.ndarray, acc_mps2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Strapdown of rate (N, 3) [rad/s, no NaN, each the mean over the step that ends at its
    stamp] from identity over stamps t_s (N,) [s]:
    (the sensor-to-start-frame quaternions (N, 4) w x y z, acc (N, 3) rotated into that frame)."""
    q = np.empty((t_s.shape[0], 4))
    acc_fixed = np.empty((t_s.shape[0], 3))
    _integrate(
        np.ascontiguousarray(t_s, dtype=float),
        np.ascontiguousarray(rate_radps, dtype=float),
        np.ascontiguousarray(acc_mps2, dtype=float),
        q,
        acc_fixed,
    )
    return q, acc_fixed


@jit
def _lowpass_pass(t_s: np.ndarray, x: np.ndarray, tau_s: float, x0: np.ndarray, out: np.ndarray, step: int) -> None:
    """One pass (step +1 forward, -1 backward) of the second-order low-pass over x (N, 3),
    starting at rest on x0 (3,); rows with a NaN hold the filter and get its value."""
    n = t_s.shape[0]
    s = np.zeros(6)
    for k in range(3):
        s[2 * k] = x0[k]
    i = 0 if step > 0 else n - 1
    prev = i
    for _ in range(n):
        ok = math.isfinite(x[i, 0]) and math.isfinite(x[i, 1]) and math.isfinite(x[i, 2])
        dt = abs(t_s[i] - t_s[prev])
        if ok and dt > 0.0:
            c = lowpass_coeffs(tau_s, dt)
            for k in range(3):
                lowpass(x[i, k], c, s, 2 * k)
        if ok:
            prev = i
        for k in range(3):
            out[i, k] = s[2 * k]
        i += step


def _combined_bias(b_f: np.ndarray, P_f: np.ndarray, b_b: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """Row-wise (P_f^-1 + P_b^-1)^-1 (P_f^-1 b_f + P_b^-1 b_b): (N, 3) biases, (N, 3, 3) covariances."""
    I_f, I_b = np.linalg.inv(P_f), np.linalg.inv(P_b)
    rhs = (I_f @ b_f[..., None] + I_b @ b_b[..., None])[..., 0]
    return np.linalg.solve(I_f + I_b, rhs[..., None])[..., 0]


def _piece(t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, p: Params) -> np.ndarray:
    """One gap-free piece: (n,) s, (n, 3) rad/s (no NaN), (n, 3) m/s^2 -> (n, 4) quaternions."""
    if p.estimate_bias:
        _, b_f, P_f = AttitudeFilter(p).update_batch(t, gyr, acc, with_bias=True)
        _, b_r, P_r = AttitudeFilter(p).update_batch(-t[::-1], -gyr[::-1], acc[::-1], with_bias=True)
        # reversed time turns the rate, and so the bias, around
        bias = _combined_bias(b_f, P_f, -b_r[::-1], P_r[::-1])
    else:
        bias = np.zeros_like(gyr)
    q3, acc_i = strapdown(t, gyr - bias, acc)
    ok = np.isfinite(acc_i).all(axis=1)
    head = ok & (t <= t[0] + p.tau_acc_s)
    x0 = acc_i[head].mean(axis=0) if head.any() else acc_i[ok][0]
    fwd = np.empty_like(acc_i)
    _lowpass_pass(t, acc_i, p.tau_acc_s, x0, fwd, 1)
    lp = np.empty_like(acc_i)
    _lowpass_pass(t, np.where(ok[:, None], fwd, np.nan), p.tau_acc_s, fwd[ok][-1], lp, -1)
    e = lp / np.linalg.norm(lp, axis=1, keepdims=True)
    qw = np.sqrt(np.clip((e[:, 2] + 1.0) * 0.5, 0.0, None))
    flip = qw <= 1e-6
    qs = np.where(flip, 1.0, qw)
    corr = np.column_stack([qw, 0.5 * e[:, 1] / qs, -0.5 * e[:, 0] / qs, np.zeros_like(qw)])
    corr[flip] = (0.0, 1.0, 0.0, 0.0)
    w1, x1, y1, z1 = corr.T
    w2, x2, y2, z2 = q3.T
    q = np.column_stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def smooth(t_s: np.ndarray, gyr_radps: np.ndarray, acc_mps2: np.ndarray, params: Params | None = None) -> np.ndarray:
    """Whole recording, offline: (N,) s [not decreasing], (N, 3) rad/s, (N, 3) m/s^2 (NaN:
    missing) -> (N, 4) sensor-to-earth quaternions (w, x, y, z). Rows before a piece's first
    complete gyroscope and accelerometer samples get that piece's first orientation."""
    p = params or Params()
    t, gyr, acc = input_rows(t_s, gyr_radps, acc_mps2)
    n = t.shape[0]
    out = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    if n == 0:
        return out
    acc = np.where((np.abs(acc) > 0).any(axis=1)[:, None], acc, np.nan)  # an all-zero row is missing
    g_ok = np.isfinite(gyr).all(axis=1)
    if not g_ok.any():
        return out
    # the gyroscope's samples back onto the stamps they describe; missing ones interpolated over
    g_t = t[g_ok] - p.gyr_delay_s
    gyr = np.column_stack([np.interp(t, g_t, gyr[g_ok, k]) for k in range(3)])
    p0 = replace(p, gyr_delay_s=0.0)
    cuts = np.flatnonzero(np.diff(t) > p.max_gap_s) + 1
    for i0, i1 in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
        a_ok = np.isfinite(acc[i0:i1]).all(axis=1)
        if not a_ok.any():
            continue
        # rows repeating the previous stamp carry nothing new: solve on the distinct stamps
        keep = np.r_[True, np.diff(t[i0:i1]) > 0]
        idx = np.flatnonzero(keep)
        q = _piece(t[i0:i1][idx], gyr[i0:i1][idx], acc[i0:i1][idx], p0)
        out[i0:i1] = q[np.cumsum(keep) - 1]
    return out
