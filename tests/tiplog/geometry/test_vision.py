"""Forward model of the shaft silhouette against the paper's inverse formulas."""

from __future__ import annotations

import numpy as np

from tiplog.geometry import so3_exp
from tiplog.geometry import vision as vg

RHO = 0.00259


def _random_axes(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = rng.uniform(-0.05, 0.05, (n, 3)) + np.array([0.0, 0.0, 0.09])
    return vg.closest_axis_point(p, u), u


def test_p0_from_normals_recovers_closest_axis_point():
    p0, u = _random_axes(200)
    n_l, n_r = vg.tangent_plane_normals(p0, u, RHO)
    np.testing.assert_allclose(vg.p0_from_normals(n_l, n_r, RHO), p0, atol=1e-12)


def test_normals_are_unit_tangent_and_orthogonal_to_axis():
    p0, u = _random_axes(200, 1)
    n_l, n_r = vg.tangent_plane_normals(p0, u, RHO)
    for n in (n_l, n_r):
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose((n * u).sum(1), 0.0, atol=1e-12)  # n^T u = 0
        np.testing.assert_allclose((n * p0).sum(1), RHO, atol=1e-12)  # tangent: axis at rho from plane
    np.testing.assert_allclose(vg.axis_direction_from_normals(n_l, n_r), u, atol=1e-9)


def test_plane_constraint_with_base_to_camera_rotation():
    rng = np.random.default_rng(2)
    A = so3_exp(rng.normal(size=3))  # base -> camera
    u_base = np.array([0.3, -0.2, -0.93])
    u_base /= np.linalg.norm(u_base)
    p0 = vg.closest_axis_point(np.array([0.01, 0.0, 0.09]), A @ u_base)
    n_l, n_r = vg.tangent_plane_normals(p0, A @ u_base, RHO)
    assert abs(vg.plane_residuals(n_l, A, u_base)) < 1e-12
    assert abs(vg.plane_residuals(n_r, A, u_base)) < 1e-12


def test_planes_about_3_6_deg_apart_at_82_mm():
    p0 = np.array([0.0, 0.0, 0.0825])
    n_l, n_r = vg.tangent_plane_normals(p0, np.array([1.0, 0.0, 0.0]), RHO)
    assert abs(180.0 - np.degrees(np.arccos(n_l @ n_r)) - 3.6) < 0.05  # planes, not normals


def test_junction_ray_intersection_recovers_depth():
    p0, u = _random_axes(100, 3)
    s_true = np.linspace(-0.03, 0.03, 100)
    x = p0 + s_true[:, None] * u
    s, point, cond = vg.ray_axis_intersection(x / np.linalg.norm(x, axis=1, keepdims=True), p0, u)
    np.testing.assert_allclose(s, s_true, atol=1e-10)
    np.testing.assert_allclose(point, x, atol=1e-10)
    assert np.all((cond >= 0) & (cond <= 1))


def test_trocar_gate_distance():
    u = np.array([1.0, 0.0, 0.0])
    p0 = np.array([0.0, 0.0, 0.09])
    n_l, n_r = vg.tangent_plane_normals(p0, u, RHO)
    rcm = p0 - 0.1 * u + np.array([0.0, 0.002, 0.0])
    dist, ok = vg.trocar_gate(n_l, n_r, RHO, rcm)
    assert abs(dist - 0.002) < 1e-9 and ok
    dist, ok = vg.trocar_gate(n_l, n_r, RHO, rcm + np.array([0.0, 0.003, 0.0]))
    assert not ok


def test_tilt_normal_changes_residual_by_angle():
    p0, u = _random_axes(50, 4)
    n_l, _ = vg.tangent_plane_normals(p0, u, RHO)
    tilted = vg.tilt_normal(n_l, np.full(50, 1e-3), np.zeros(50), u)
    np.testing.assert_allclose((tilted * u).sum(1), np.sin(1e-3), rtol=1e-5)
