"""Rotations and rigid transforms, pure numpy, vectorised over leading axes.

Conventions: rotation matrices act on column vectors (`v_base = R_base_tool @ v_tool`);
quaternions are Hamilton, stored (x, y, z, w) as Foxglove does; rotation vectors in radians.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices, skew(a) @ b == a x b."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) [rad] -> rotation matrices (..., 3, 3) (Rodrigues)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> rotation vectors (..., 3) [rad], angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    q = rot_to_quat(R)
    xyz, w = q[..., :3], q[..., 3:4]
    n = np.linalg.norm(xyz, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(n, w)
    scale = np.where(n < _EPS, 2.0 / np.where(np.abs(w) < _EPS, 1.0, w), angle / np.where(n < _EPS, 1.0, n))
    return xyz * scale


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle [rad] of rotation matrices (..., 3, 3), robust near 0 and pi."""
    return np.linalg.norm(so3_log(R), axis=-1)


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) as (x, y, z, w), w >= 0."""
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Four candidate forms; pick the best-conditioned per element (Shepperd's method).
    t = np.stack([m00 + m11 + m22, m00 - m11 - m22, -m00 + m11 - m22, -m00 - m11 + m22], -1)
    k = np.argmax(t, axis=-1)
    s = np.sqrt(np.maximum(1.0 + np.take_along_axis(t, k[..., None], -1)[..., 0], _EPS)) * 2.0
    r21, r12 = R[..., 2, 1], R[..., 1, 2]
    r02, r20 = R[..., 0, 2], R[..., 2, 0]
    r10, r01 = R[..., 1, 0], R[..., 0, 1]
    cand = np.stack(
        [
            np.stack([(r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s], -1),
            np.stack([0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s], -1),
            np.stack([(r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s], -1),
            np.stack([(r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s], -1),
        ],
        -2,
    )
    q = np.take_along_axis(cand, k[..., None, None].repeat(4, -1), -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) as (x, y, z, w) -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rot_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector a onto unit vector b (both (3,))."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: rotate pi about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return so3_exp(np.pi * axis / np.linalg.norm(axis))
    K = skew(v)
    return np.eye(3) + K + K @ K / (1.0 + c)


def transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from rotation (3, 3) and translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def point_line_distance(x: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance from points x (..., 3) to the line origin + s*direction (unit), same units."""
    d = np.asarray(x, float) - origin
    u = np.asarray(direction, float)
    return np.linalg.norm(d - (d * u).sum(-1, keepdims=True) * u, axis=-1)
