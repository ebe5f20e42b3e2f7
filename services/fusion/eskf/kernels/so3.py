"""Rotation maths for the hot loops, one scalar form each, compiled with numba: the SO(3)
exponential, the cross product and its matrix, the quaternion product and a quaternion's
matrix. The batch forms over arrays of rotations (and the logarithm) are `tiplog.geometry`.

Conventions, as in `tiplog.geometry`: rotation matrices act on column vectors
(v_base = R_base_tool @ v_tool); rotation vectors in radians; quaternions Hamilton. Quaternion
order: (w, x, y, z) here, the order of the attitude filter's state and of `tiplog fusion
attitude`'s CSV; `tiplog.geometry` and the bus messages store (x, y, z, w), as Foxglove does."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit


@njit(cache=True, fastmath=False)
def exp_into(wx: float, wy: float, wz: float, out: np.ndarray) -> None:
    """Rotation vector (wx, wy, wz) [rad] -> its rotation matrix written into out (3, 3)."""
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-12:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    out[0, 0] = 1.0 - b * (wy * wy + wz * wz)
    out[1, 1] = 1.0 - b * (wx * wx + wz * wz)
    out[2, 2] = 1.0 - b * (wx * wx + wy * wy)
    out[0, 1] = -a * wz + b * wx * wy
    out[1, 0] = a * wz + b * wx * wy
    out[0, 2] = a * wy + b * wx * wz
    out[2, 0] = -a * wy + b * wx * wz
    out[1, 2] = -a * wx + b * wy * wz
    out[2, 1] = a * wx + b * wy * wz


@njit(cache=True)
def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) [rad] -> rotation matrix (3, 3)."""
    out = np.empty((3, 3))
    exp_into(w[0], w[1], w[2], out)
    return out


@njit(cache=True)
def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for (3,) vectors."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True)
def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) cross-product matrix, skew(a) @ b == a x b."""
    out = np.zeros((3, 3))
    out[0, 1], out[0, 2], out[1, 0] = -v[2], v[1], v[2]
    out[1, 2], out[2, 0], out[2, 1] = -v[0], -v[1], v[0]
    return out


@njit(cache=True, nogil=True)
def quat_mul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = a b, normalised; quaternions (w, x, y, z). out may be a or b."""
    w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    n = math.sqrt(w * w + x * x + y * y + z * z)
    out[0], out[1], out[2], out[3] = w / n, x / n, y / n, z / n


@njit(cache=True, nogil=True)
def quat_matrix(q: np.ndarray, R: np.ndarray) -> None:
    """Rotation matrix (row-major, 9) of the unit quaternion q (w, x, y, z), written into R."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0], R[1], R[2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[3], R[4], R[5] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[6], R[7], R[8] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
