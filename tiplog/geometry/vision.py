"""Geometry of a cylindrical shaft seen by a pinhole camera, pure numpy, vectorised.

Everything is in the camera frame (x right, y down, z forward, metres) unless a name says
otherwise. The shaft is a cylinder of radius rho_s about the axis line {P0 + s u}. Each
silhouette line and the camera centre span a plane tangent to the cylinder; its unit normal
n is oriented toward the axis (n . P0 = +rho_s). Then (paper, Sec. Markerless Shaft
Geometry): n_i . u = 0 for i in {L, R}, and the closest axis point to the camera is
P0 = rho_s (n_L + n_R) / (1 + n_L . n_R). Shared by the bench (forward model), the vision
service (inverse) and the estimator (plane constraints, trocar gate).
"""

from __future__ import annotations

import numpy as np


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def closest_axis_point(p_on_axis: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Closest point of the line {p + s u} (u unit, (..., 3)) to the camera centre, (..., 3)."""
    p = np.asarray(p_on_axis, dtype=float)
    u = np.asarray(u, dtype=float)
    return p - (p * u).sum(-1, keepdims=True) * u


def tangent_plane_normals(p0: np.ndarray, u: np.ndarray, rho_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (n_L, n_R), each (..., 3), of the two planes through the camera centre
    tangent to the cylinder of radius rho_s [m] about the axis through closest point p0 with
    direction u: n = a e +- b (e x u) with e = p0/|p0|, a = rho_s/|p0| (n_L takes +), so
    that n_L x n_R is along u. NaN where the camera is inside the cylinder."""
    p0 = np.asarray(p0, dtype=float)
    u = _unit(u)
    dist = np.linalg.norm(p0, axis=-1, keepdims=True)
    e = p0 / dist
    w = np.cross(e, u)
    a = rho_s / dist
    with np.errstate(invalid="ignore"):
        b = np.sqrt(1.0 - a * a)
    return a * e + b * w, a * e - b * w


def p0_from_normals(n_l: np.ndarray, n_r: np.ndarray, rho_s: float) -> np.ndarray:
    """Closest axis point P0 = rho_s (n_L + n_R) / (1 + n_L . n_R), (..., 3) [m]."""
    n_l = np.asarray(n_l, dtype=float)
    n_r = np.asarray(n_r, dtype=float)
    c = (n_l * n_r).sum(-1, keepdims=True)
    return rho_s * (n_l + n_r) / (1.0 + c)


def axis_direction_from_normals(n_l: np.ndarray, n_r: np.ndarray) -> np.ndarray:
    """Axis direction n_L x n_R normalised (..., 3): ill-conditioned (planes ~3.6 deg apart);
    the sign follows tangent_plane_normals' convention (points along u)."""
    return _unit(np.cross(n_l, n_r))


def plane_residuals(n: np.ndarray, A: np.ndarray, u_base: np.ndarray) -> np.ndarray:
    """n^T A u for normals n (..., 3), base-to-camera rotations A (..., 3, 3), shaft
    directions u in the base frame (..., 3): zero for a consistent observation (radians,
    as the sine of the angle between u and the plane)."""
    Au = np.einsum("...ij,...j->...i", np.asarray(A, float), np.asarray(u_base, float))
    return (np.asarray(n, float) * Au).sum(-1)


def image_line(n: np.ndarray) -> np.ndarray:
    """Silhouette line in normalised (undistorted) image coordinates: a x + b y + c = 0 with
    (a, b, c) = n, scaled so that a^2 + b^2 = 1 (..., 3)."""
    n = np.asarray(n, dtype=float)
    return n / np.linalg.norm(n[..., :2], axis=-1, keepdims=True)


def ray_axis_intersection(ray: np.ndarray, p0: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Back-projected ray {t d} (d unit, through the camera centre) against the axis line
    {p0 + s u}: returns (s, point on the axis (..., 3), conditioning 1 - (d.u)^2). s is the
    axis coordinate from p0 of the point closest to the ray [m]; the paper rejects frames
    whose conditioning is below 0.45 rather than down-weighting them."""
    d = _unit(ray)
    u = _unit(u)
    p0 = np.asarray(p0, dtype=float)
    du = (d * u).sum(-1)
    cond = 1.0 - du * du
    # minimise |t d - p0 - s u|: normal equations [1 -du; du -1][t s]^T = [d.p0; u.p0]
    dp = (d * p0).sum(-1)
    up = (u * p0).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (du * dp - up) / cond
    return s, p0 + s[..., None] * u, cond


def line_point_distance(point: np.ndarray, p_on_line: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance from point(s) (..., 3) to the line {p + s direction} (trocar gate), same units."""
    d = np.asarray(point, float) - np.asarray(p_on_line, float)
    u = _unit(direction)
    return np.linalg.norm(d - (d * u).sum(-1, keepdims=True) * u, axis=-1)


def trocar_gate(
    n_l: np.ndarray, n_r: np.ndarray, rho_s: float, rcm_cam_m: np.ndarray, max_dist_m: float = 0.0035
) -> tuple[np.ndarray, np.ndarray]:
    """(distance [m], passes) of the registered RCM (camera frame) to the shaft line
    reconstructed from the two normals alone (P0 and n_L x n_R)."""
    p0 = p0_from_normals(n_l, n_r, rho_s)
    dist = line_point_distance(rcm_cam_m, p0, axis_direction_from_normals(n_l, n_r))
    return dist, dist <= max_dist_m


def tilt_normal(n: np.ndarray, angle_a: np.ndarray, angle_b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Rotate unit normals n (..., 3) by small angles [rad]: angle_a toward u (changes n.u,
    the plane-constraint residual) and angle_b toward n x u (moves the plane's offset)."""
    n = np.asarray(n, float)
    u = _unit(u)
    t1 = _unit(u - (u * n).sum(-1, keepdims=True) * n)
    t2 = np.cross(n, t1)
    a = np.asarray(angle_a, float)[..., None]
    b = np.asarray(angle_b, float)[..., None]
    return _unit(n + a * t1 + b * t2)


def normal_from_image_line(line_px: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Unit normal (..., 3), camera frame, of the plane through the camera centre whose image is the
    line a u + b v + c = 0 in undistorted pixels (line_px (..., 3)); signed like the line: n . X > 0
    for points X whose pixels give a u + b v + c > 0 (the inside of a silhouette edge)."""
    line = np.asarray(line_px, dtype=float)
    a, b, c = line[..., 0], line[..., 1], line[..., 2]
    return _unit(np.stack([a * fx, b * fy, a * cx + b * cy + c], -1))


def line_from_normal(n: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Inverse of `normal_from_image_line`: the plane's image line (..., 3) in undistorted pixels,
    (a, b) unit, signed like n."""
    n = np.asarray(n, dtype=float)
    a, b = n[..., 0] / fx, n[..., 1] / fy
    c = n[..., 2] - a * cx - b * cy
    return np.stack([a, b, c], -1) / np.hypot(a, b)[..., None]


def junction_on_axis(
    ray: np.ndarray, p0: np.ndarray, u: np.ndarray, rho_s: float, rim: bool = True, rim_fraction: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis point [m] (..., 3) of the shaft junction seen along `ray` (camera frame, through the
    camera centre), with its axis coordinate s from p0 [m] and the conditioning 1 - (d.u)^2.

    With rim=True the ray is taken to graze the end rim of the shaft on its side nearest the
    camera, as the silhouette's end does on the image's centre line: since p0 is the axis point
    closest to the camera, that rim runs along the line {p0 (1 - rho_s/|p0|) + s u}, parallel to
    the axis, and the ray is intersected with it; rim=False intersects with the axis itself. A
    junction located off the centre line, on lines a fraction f of the radius to either side and
    averaged, grazes the rim rim_fraction = sqrt(1 - f^2) of rho_s nearer the camera instead."""
    p0 = np.asarray(p0, dtype=float)
    off = rho_s * rim_fraction
    base = p0 * (1.0 - off / np.linalg.norm(p0, axis=-1, keepdims=True)) if rim else p0
    s, _, cond = ray_axis_intersection(ray, base, u)
    return p0 + s[..., None] * _unit(u), s, cond
