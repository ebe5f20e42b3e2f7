"""The trocar's remote centre of motion (RCM): the shaft passes through it (a 2-D
pseudo-measurement), and the shaft's point there is the one at rest while the tool pivots (the
gravity model's lever arm, `port_lever`)."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import mtv
from services.fusion.eskf.layout import N


@njit(cache=True)
def rcm_jacobian(R: np.ndarray, p: np.ndarray, rcm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H (2, 16), y (2,)) of the RCM pseudo-measurement (R^T (r - p))_xy = 0."""
    d = mtv(R, rcm - p)
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
