"""The gravity model's Jacobian is the derivative of its prediction."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.layout import N
from services.fusion.eskf.models.gravity import gravity_jacobian
from tiplog.geometry import so3_exp

G = np.array([0.0, 0.0, -9.80665])


def test_gravity_jacobian_is_the_derivative_of_its_prediction():
    """The gravity update's H against finite differences of its own innovation, in attitude
    (tool coordinates, R Exp(dtheta)) and accelerometer bias, with a lever arm, a rate and an
    angular acceleration (the centripetal and tangential terms)."""
    rng = np.random.default_rng(5)
    R, R_ti = so3_exp(rng.normal(size=3)), so3_exp(rng.normal(size=3))
    lever = rng.normal(size=3) * 0.2
    w = rng.normal(size=3)
    bg = rng.normal(size=3) * 0.01
    ba = rng.normal(size=3) * 0.05
    alpha = rng.normal(size=3) * 2.0
    f_meas = rng.normal(size=3) + np.array([0.0, 0.0, 9.8])
    H, y0 = gravity_jacobian(R, R_ti, lever, w, bg, ba, alpha, f_meas)
    # at zero lever arm and rate the prediction is gravity in the IMU frame plus the bias
    _, y_still = gravity_jacobian(R, R_ti, np.zeros(3), bg, bg, ba, np.zeros(3), f_meas)
    np.testing.assert_allclose(f_meas - y_still, R_ti.T @ R.T @ (-G) + ba, atol=1e-12)
    eps = 1e-6
    for j in range(N):
        d = np.zeros(N)
        d[j] = eps
        Rj = R @ so3_exp(d[6:9])
        _, yj = gravity_jacobian(Rj, R_ti, lever, w, bg, ba + d[12:15], alpha, f_meas)
        # the innovation falls by H dx
        np.testing.assert_allclose((y0 - yj) / eps, H[:, j], atol=1e-5, err_msg=str(j))
    assert np.abs(H[:, 6:9]).max() > 1.0 and np.array_equal(H[:, 12:15], np.eye(3))
