"""The vision models: a pose that agrees with the frame gives no innovation, and each Jacobian
is the derivative of its prediction (position, and attitude as R Exp(dtheta))."""

from __future__ import annotations

import numpy as np
import pytest

from services.fusion.eskf.layout import N
from services.fusion.eskf.models.vision import junction_ray, tangent_planes
from tiplog.geometry import so3_exp
from tiplog.geometry import vision as vg

RADIUS, OFFSET = 0.00259, 0.004


def _scene(seed: int):
    """(R, p, A, cam) of a shaft in front of a camera, and the frame it gives: tangent-plane
    normals n (2, 3) and the junction ray d, camera coordinates."""
    rng = np.random.default_rng(seed)
    R = so3_exp(rng.normal(size=3) * 0.3) @ so3_exp(np.array([np.pi, 0.0, 0.0]))  # shaft pointing down
    p = np.array([0.6, 0.05, 0.15])
    A = so3_exp(rng.normal(size=3)).T  # base -> camera
    u_c = A @ R[:, 2]
    # the camera 0.1 m from the junction, off the shaft's line
    side = np.cross(u_c, rng.normal(size=3))
    J_c = 0.1 * side / np.linalg.norm(side) + 0.02 * u_c
    cam = p - OFFSET * R[:, 2] - A.T @ J_c
    n = np.stack(vg.tangent_plane_normals(vg.closest_axis_point(J_c, u_c), u_c, RADIUS))
    return R, p, A, cam, n, J_c / np.linalg.norm(J_c)


def _moved(R, p, dx):
    return R @ so3_exp(dx[6:9]), p + dx[0:3]


def test_a_pose_that_agrees_with_the_frame_has_no_innovation():
    for seed in range(5):
        R, p, A, cam, n, d = _scene(seed)
        _, y = tangent_planes(R, p, n, A, cam, RADIUS)
        np.testing.assert_allclose(y, 0.0, atol=1e-12)
        _, y, resid = junction_ray(R, p, d, A, cam, OFFSET)
        np.testing.assert_allclose(y, 0.0, atol=1e-12)
        np.testing.assert_allclose(resid, 0.0, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_the_jacobians_are_the_derivatives_of_the_predictions(seed):
    R, p, A, cam, n, d = _scene(seed)

    def planes(R_, p_):
        return tangent_planes(R_, p_, n, A, cam, RADIUS)

    def ray(R_, p_):
        return junction_ray(R_, p_, d, A, cam, OFFSET)[:2]

    eps = 1e-7
    for model in (planes, ray):
        H, y0 = model(R, p)
        for j in range(N):
            dx = np.zeros(N)
            dx[j] = eps
            _, yj = model(*_moved(R, p, dx))
            # the innovation falls by H dx
            np.testing.assert_allclose((y0 - yj) / eps, H[:, j], atol=1e-6, err_msg=f"{model.__name__} {j}")
        assert not H[:, 3:6].any() and not H[:, 9:].any()  # position and attitude only
