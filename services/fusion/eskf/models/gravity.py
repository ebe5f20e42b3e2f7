"""The accelerometer's specific force predicted as gravity plus the lever arm's terms: with those
terms taken off, what is left tells the tool's tilt."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.kernels.linalg import mtv, mv
from services.fusion.eskf.kernels.propagate import lever_accel
from services.fusion.eskf.layout import N


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
    w_t = mv(R_ti, w_imu - bg)
    a_t = -lever_accel(w_t, alpha_tool, r_lever_tool)  # the IMU's acceleration (far end at rest), tool coordinates
    w = np.empty(3)  # R^T (-g): gravity's share, in tool coordinates
    for i in range(3):
        w[i] = 9.80665 * R[2, i]
    f_pred = mtv(R_ti, a_t + w) + ba
    H = np.zeros((3, N))
    # R_ti^T skew(w)
    for i in range(3):
        H[i, 6] = R_ti[1, i] * w[2] - R_ti[2, i] * w[1]
        H[i, 7] = R_ti[2, i] * w[0] - R_ti[0, i] * w[2]
        H[i, 8] = R_ti[0, i] * w[1] - R_ti[1, i] * w[0]
        H[i, 12 + i] = 1.0
    return H, f_imu - f_pred
