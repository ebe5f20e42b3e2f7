"""The labeler against the renderer's exact geometry at fixed poses."""

from __future__ import annotations

import numpy as np
import pytest

from services.vision import edges
from services.vision.labeler import JUNCTION_RIM_FRACTION, LabelerParams, label_frame, label_mask
from tests.services.vision.conftest import JUNCTION_M, SHAFT_RADIUS_M
from tiplog.geometry import vision as vg


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def test_tangent_planes_match_the_rendered_silhouette(rendered, camera):
    K = (camera.fx, camera.fy, camera.cx, camera.cy)
    for img, truth, T in rendered:
        lab = label_frame(img, camera)
        assert lab.ok, lab.reason
        n_l = vg.normal_from_image_line(lab.line_left, *K)
        n_r = vg.normal_from_image_line(lab.line_right, *K)
        # left/right and orientation as the renderer (and tiplog.geometry.vision) define them
        assert _angle_deg(n_l, truth["n_left_cam"]) < 0.05
        assert _angle_deg(n_r, truth["n_right_cam"]) < 0.05
        assert np.cross(n_l, n_r) @ T[:3, 2] > 0  # n_L x n_R along the shaft toward the tip
        assert abs(np.degrees(np.arcsin(n_l @ T[:3, 2]))) < 0.05  # plane constraint n.u = 0
        assert lab.residual_px < 0.5


def test_junction_on_the_axis_within_half_a_millimetre(rendered, camera):
    for img, _truth, T in rendered:
        lab = label_frame(img, camera)
        assert lab.junction_visible
        u = T[:3, 2]
        J = T[:3, 3] - JUNCTION_M * u
        ray = camera.pixel_to_ray(lab.junction_px, distorted=False)
        p0 = vg.closest_axis_point(J, u)
        on_rim, _, cond = vg.junction_on_axis(ray, p0, u, SHAFT_RADIUS_M, True, JUNCTION_RIM_FRACTION)
        on_axis, _, _ = vg.junction_on_axis(ray, p0, u, SHAFT_RADIUS_M, rim=False)
        assert cond > 0.45
        assert abs((on_rim - J) @ u) < 0.1e-3
        # without the rim model the junction is biased distally by about rho f (d.u) / sqrt(1 - (d.u)^2)
        assert abs((on_axis - J) @ u) > abs((on_rim - J) @ u)


def test_mask_agrees_with_the_rendered_mask(rendered, camera):
    h, w = camera.height // 4, camera.width // 4
    uv = edges.grid_undistorted(camera, 4.0, 1.5, h, w)
    for img, truth, _ in rendered:
        m = label_mask(label_frame(img, camera), uv)
        t = truth["mask"][1::4, 1::4]  # pixels at 4 j + 1 .. the nearest to 4 j + 1.5
        iou = (m & t).sum() / (m | t).sum()
        assert iou > 0.9


def test_deterministic_and_pure(rendered, camera):
    img = rendered[0][0]
    before = img.copy()
    a, b = label_frame(img, camera), label_frame(img, camera)
    assert np.array_equal(img, before)
    assert np.array_equal(a.line_left, b.line_left) and np.array_equal(a.junction_px, b.junction_px)


def test_no_shaft_is_a_reason_not_an_error(blank_frame, camera):
    lab = label_frame(blank_frame, camera)
    assert not lab.ok and lab.reason == "no_shaft"


def test_thresholds_are_parameters(rendered, camera):
    lab = label_frame(rendered[0][0], camera, LabelerParams(dark_threshold=1.0))
    assert not lab.ok and lab.reason == "no_shaft"


def test_rim_line_geometry_recovers_the_axis_point():
    """A ray through a point rho_s * f nearer the camera than the axis point J, on the plane of
    the axis and the camera centre, is moved back onto J."""
    rho, f = 0.0026, 0.6
    u = np.array([0.95, 0.1, 0.3])
    u /= np.linalg.norm(u)
    J = np.array([0.01, -0.005, 0.09])
    p0 = vg.closest_axis_point(J, u)
    rim_point = J - rho * f * p0 / np.linalg.norm(p0)
    ray = rim_point / np.linalg.norm(rim_point)
    on_axis, s, cond = vg.junction_on_axis(ray, p0, u, rho, True, f)
    assert np.allclose(on_axis, J, atol=1e-9) and 0 < cond <= 1
    assert np.allclose(p0 + s * u, J, atol=1e-9)


def test_image_line_and_plane_normal_are_inverse(camera):
    K = (camera.fx, camera.fy, camera.cx, camera.cy)
    n = np.array([0.03, -0.998, 0.05])
    n /= np.linalg.norm(n)
    line = vg.line_from_normal(n, *K)
    assert np.hypot(line[0], line[1]) == pytest.approx(1.0)
    assert np.allclose(vg.normal_from_image_line(line, *K), n)
