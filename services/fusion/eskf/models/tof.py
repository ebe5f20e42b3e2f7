"""The ToF range through the ray-plane model: the beam from its origin on the tool meets the
target plane, plus the range offset b_rho."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import mtv, mv
from services.fusion.eskf.layout import N


@njit(cache=True)
def tof_jacobian(
    R: np.ndarray, p: np.ndarray, brho: float, m: np.ndarray, h: float, o: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """(H (1, 16), predicted range [m], m.(R b)) of rho = (h - m.(p + R o)) / (m.(R b)) + b_rho."""
    Ro = mv(R, o)
    Rb = mv(R, b)
    den = m[0] * Rb[0] + m[1] * Rb[1] + m[2] * Rb[2]
    H = np.zeros((1, N))
    if den < 1e-9:
        return H, 0.0, den
    num = h - (m[0] * (p[0] + Ro[0]) + m[1] * (p[1] + Ro[1]) + m[2] * (p[2] + Ro[2]))
    mR = mtv(R, m)
    # mR @ skew(o) and mR @ skew(b)
    so = np.array([mR[1] * o[2] - mR[2] * o[1], mR[2] * o[0] - mR[0] * o[2], mR[0] * o[1] - mR[1] * o[0]])
    sb = np.array([mR[1] * b[2] - mR[2] * b[1], mR[2] * b[0] - mR[0] * b[2], mR[0] * b[1] - mR[1] * b[0]])
    k = num / (den * den)
    for j in range(3):
        H[0, j] = -m[j] / den
        H[0, 6 + j] = so[j] / den + k * sb[j]
    H[0, 15] = 1.0
    return H, num / den + brho, den
