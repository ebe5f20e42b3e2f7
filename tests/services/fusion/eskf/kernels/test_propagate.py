"""Propagation against plain numpy: the covariance step is F P F^T + Q with the F that
`transition` gives the smoother, and F is the derivative of the nominal step."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.kernels.propagate import propagate, transition
from services.fusion.eskf.kernels.so3 import skew
from services.fusion.eskf.layout import N
from tiplog.geometry import so3_exp


def test_propagate_is_f_p_ft_plus_q():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(N, N))
    P0 = X @ X.T * 1e-4 + np.eye(N) * 1e-6
    R = so3_exp(rng.normal(size=3))
    R_ti = so3_exp(rng.normal(size=3))
    lever, w, f, bg, ba, alpha = (rng.normal(size=3) for _ in range(6))
    q = np.abs(rng.normal(size=N)) * 1e-3
    dt = 0.005
    P = P0.copy()
    Rk = R.copy()
    p, v = np.zeros(3), np.zeros(3)
    propagate(p, v, Rk, P, bg, ba, w, f, alpha, R_ti, lever, q, 0.01, 0.02, dt, True)
    w_tool, f_tool = R_ti @ (w - bg), R_ti @ (f - ba)
    a_tool = f_tool + np.cross(alpha, lever) + np.cross(w_tool, np.cross(w_tool, lever))
    F = np.eye(N)
    F[0:3, 3:6] = np.eye(3) * dt
    F[3:6, 6:9] = -R @ skew(a_tool) * dt
    F[3:6, 12:15] = -R @ R_ti * dt
    F[0:3, 6:9] = -R @ skew(a_tool) * dt * dt / 2
    F[0:3, 12:15] = -R @ R_ti * dt * dt / 2
    F[6:9, 6:9] = so3_exp(-w_tool * dt)
    F[6:9, 9:12] = -R_ti * dt
    # the smoother's F is the one the filter applies
    np.testing.assert_allclose(transition(R, bg, ba, w, f, alpha, R_ti, lever, dt, True), F, atol=1e-15)
    Q = q.copy()
    Q[9:12] = (0.01 + 0.02 * np.linalg.norm(w_tool)) ** 2
    np.testing.assert_allclose(P, F @ P0 @ F.T + np.diag(Q * dt), rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(Rk, R @ so3_exp(w_tool * dt), atol=1e-12)


def test_the_propagation_jacobian_is_the_derivative_of_the_step():
    """Each attitude and accelerometer-bias column of F against finite differences of the
    nominal step: the lever arm's centripetal and tangential terms turn with the tool, as the
    specific force does, and the position takes half a step of the changed acceleration."""
    rng = np.random.default_rng(3)
    R, R_ti = so3_exp(rng.normal(size=3)), so3_exp(rng.normal(size=3))
    lever = np.array([-0.018, 0.0, 0.304])
    w, f, alpha = rng.normal(size=3) * 2.0, np.array([0.3, -9.5, 1.2]), rng.normal(size=3) * 20.0
    bg, ba, dt, eps = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01, 0.005, 1e-7

    def step(Rx, bax):
        p, v, P = np.zeros(3), np.array([0.01, -0.02, 0.03]), np.eye(N)
        propagate(p, v, Rx.copy(), P, bg, bax, w, f, alpha, R_ti, lever, np.zeros(N), 0.0, 0.0, dt, True)
        return np.concatenate([p, v])

    F = transition(R, bg, ba, w, f, alpha, R_ti, lever, dt, True)
    base = step(R, ba)
    for j in range(3):
        e = np.zeros(3)
        e[j] = eps
        np.testing.assert_allclose((step(R @ so3_exp(e), ba) - base) / eps, F[0:6, 6 + j], rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose((step(R, ba + e) - base) / eps, F[0:6, 12 + j], rtol=1e-5, atol=1e-9)
