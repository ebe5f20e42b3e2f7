"""A published sample's numbers from a state in one compiled call (`eskf.sample`), made at every
gyro sample: the quaternion, depth, tilt, roll and the sigmas."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.update import finite


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
