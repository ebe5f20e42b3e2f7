"""The compiled update against the textbook one, and the covariance's reset to a new estimate
against the change of coordinates of the invariant error."""

from __future__ import annotations

import numpy as np
import pytest

from services.fusion.eskf.kernels.so3 import skew
from services.fusion.eskf.kernels.update import reset, update
from services.fusion.eskf.layout import N
from tiplog.geometry import so3_exp

RCM = np.array([0.65, 0.0, 0.30])


def test_update_is_the_textbook_update():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(N, N))
    P0 = X @ X.T * 1e-4 + np.eye(N) * 1e-6
    H = rng.normal(size=(2, N))
    y = rng.normal(size=2) * 1e-3
    r = np.array([1e-6, 2e-6])
    P = P0.copy()
    status, nis, dx = update(P, H, y, r, 1e9, 0, N)
    S = H @ P0 @ H.T + np.diag(r)
    K = P0 @ H.T @ np.linalg.inv(S)
    assert status == 0
    np.testing.assert_allclose(dx, K @ y, rtol=1e-9)
    np.testing.assert_allclose(P, P0 - K @ S @ K.T, rtol=1e-8, atol=1e-14)
    assert nis == pytest.approx(y @ np.linalg.solve(S, y))


def _invariant_T(p: np.ndarray, v: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Local error = T @ right-invariant error: dp = xi_p - [q]x xi_R, dv = xi_v - [v]x xi_R,
    dtheta = R^T xi_R (q = p - RCM)."""
    T = np.eye(N)
    T[0:3, 6:9] = -skew(p - RCM)
    T[3:6, 6:9] = -skew(v)
    T[6:9, 6:9] = R.T
    return T


def test_reset_carries_the_covariance_of_the_invariant_error_to_the_new_estimate():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(N, N))
    P = A @ A.T + np.eye(N)
    R0, p0, v0 = so3_exp(rng.normal(size=3)), RCM + rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.05
    dtheta, dp, dv = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01
    dR = so3_exp(dtheta)
    G = _invariant_T(p0 + dp, v0 + dv, R0 @ dR) @ np.linalg.inv(_invariant_T(p0, v0, R0))
    out = P.copy()
    reset(out, R0, dR, dp, dv)
    np.testing.assert_allclose(out, G @ P @ G.T, rtol=1e-10, atol=1e-12)
