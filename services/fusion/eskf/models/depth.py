"""The tip's depth along the shaft from the RCM: what it is (`shaft_depth`, compiled: it is asked
at every ToF range and, without vision, at every gyro sample), and the pull towards the working
depth while vision is away (`anchor`)."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.layout import IP, N


@njit(cache=True)
def shaft_depth(R: np.ndarray, p: np.ndarray, rcm: np.ndarray) -> float:
    """The tip's depth along the shaft R[:, 2] from the RCM, u . (p - rcm) [m] (numpy's
    `u @ (p - rcm)` to the bit, in one call instead of three array operations)."""
    return R[0, 2] * (p[0] - rcm[0]) + R[1, 2] * (p[1] - rcm[1]) + R[2, 2] * (p[2] - rcm[2])


def anchor(R: np.ndarray, depth_m: float, ref_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(H (1, 16), y (1,)) of the depth pseudo-measurement: the depth `depth_m` (`shaft_depth`
    of the state) measured as the working depth `ref_m`. H is the shaft direction on the
    position block: with the tip on the shaft line, turning the shaft leaves the depth
    unchanged to first order."""
    H = np.zeros((1, N))
    H[0, IP] = R[:, 2]
    return H, np.array([ref_m - depth_m])
