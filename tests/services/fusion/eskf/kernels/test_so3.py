"""The scalar numba forms of eskf/kernels/so3 agree with the batch forms of tiplog.geometry (one
convention: matrices act on column vectors, Hamilton quaternions; (w, x, y, z) in so3)."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.kernels.so3 import cross, exp_so3, quat_matrix, quat_mul, skew
from tiplog.geometry import quat_to_rot, so3_exp, so3_log
from tiplog.geometry import skew as skew_batch


def _rotvecs(n: int = 50) -> np.ndarray:
    rng = np.random.default_rng(7)
    scale = rng.choice([1e-9, 1e-4, 0.1, 1.0, 3.0], size=(n, 1))
    return rng.normal(size=(n, 3)) * scale


def test_exp_matches_the_batch_form_and_inverts_the_log():
    for w in _rotvecs():
        R = exp_so3(w)
        np.testing.assert_allclose(R, so3_exp(w), atol=1e-14)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        if np.linalg.norm(w) < np.pi:
            np.testing.assert_allclose(so3_log(R), w, atol=1e-9)


def test_cross_and_skew_are_the_cross_product():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        np.testing.assert_array_equal(cross(a, b), np.cross(a, b))
        np.testing.assert_array_equal(skew(a), skew_batch(a))
        np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=1e-15)


def _wxyz(w: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of rotation vector w."""
    th = np.linalg.norm(w)
    axis = w / th if th > 0 else np.zeros(3)
    return np.concatenate([[np.cos(th / 2)], np.sin(th / 2) * axis])


def test_quaternion_product_composes_rotations_in_the_documented_order():
    ws = _rotvecs(20)
    for a, b in zip(ws[:-1], ws[1:], strict=True):
        qa, qb = _wxyz(a), _wxyz(b)
        q = np.empty(4)
        quat_mul(qa, qb, q)
        R = np.empty(9)
        quat_matrix(q, R)
        np.testing.assert_allclose(R.reshape(3, 3), exp_so3(a) @ exp_so3(b), atol=1e-12)
        # tiplog.geometry stores (x, y, z, w)
        np.testing.assert_allclose(quat_to_rot(np.roll(q, -1)), exp_so3(a) @ exp_so3(b), atol=1e-12)
