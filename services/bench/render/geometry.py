"""Exact geometry of the instrument for the pixel renderer: tangent planes, silhouette lines,
ray casting against the shaft, its distal end face and the jaws.

Frames: camera frame as in tiplog.geometry.camera (x right, y down, z forward, metres); the
instrument axis is parametrised by s [m] along the tool z axis (distal positive) with s = 0 at
the tip, so the shaft occupies s <= -junction and the jaws -junction <= s <= 0.
Lines are (a, b, c) with a*u + b*v + c = 0 in undistorted pixels, a^2 + b^2 = 1, positive on
the instrument's side, so a*u + b*v + c is the signed pixel distance into the silhouette.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.geometry.camera import CameraModel

PART_NONE, PART_SHAFT, PART_END_FACE, PART_JAWS, PART_JAW_TIP = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class InstrumentGeometry:
    """The instrument in the camera frame: tip position [m], unit distal axis, radii [m],
    junction distance from the tip [m] and shaft length proximal of the junction [m]."""

    p_tip_cam_m: np.ndarray
    axis_cam: np.ndarray
    shaft_radius_m: float
    jaw_radius_m: float
    junction_m: float
    shaft_length_m: float

    @classmethod
    def from_pose(
        cls,
        T_camera_tool: np.ndarray,
        shaft_radius_m: float,
        jaw_radius_m: float,
        junction_m: float,
        shaft_length_m: float,
    ) -> InstrumentGeometry:
        T = np.asarray(T_camera_tool, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_camera_tool must be a finite 4x4 matrix (got shape {T.shape})")
        R = T[:3, :3]
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        if err > 1e-3:
            raise ValueError(f"T_camera_tool rotation is not orthonormal (max |R^T R - I| = {err:.2e})")
        axis = R[:, 2] / np.linalg.norm(R[:, 2])
        return cls(T[:3, 3].copy(), axis, shaft_radius_m, jaw_radius_m, junction_m, shaft_length_m)

    def point(self, s_m: float | np.ndarray) -> np.ndarray:
        """Axis point(s) at s [m] from the tip, camera frame [m]."""
        return self.p_tip_cam_m + np.multiply.outer(s_m, self.axis_cam)

    @property
    def s_junction(self) -> float:
        return -self.junction_m

    @property
    def s_proximal(self) -> float:
        return -(self.junction_m + self.shaft_length_m)


def tangent_normals(p_axis_cam_m: np.ndarray, axis_cam: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (camera frame) of the two planes through the camera centre tangent to the
    infinite cylinder; both satisfy n . X >= 0 on the cylinder (n . axis_point = radius)."""
    d = axis_cam / np.linalg.norm(axis_cam)
    a_perp = p_axis_cam_m - np.dot(p_axis_cam_m, d) * d
    h = float(np.linalg.norm(a_perp))
    if h <= radius_m * 1.001:
        raise ValueError(f"camera centre is inside or on the instrument cylinder (axis distance {h * 1e3:.2f} mm)")
    e1 = a_perp / h
    e2 = np.cross(d, e1)
    c = radius_m / h
    s = np.sqrt(1.0 - c * c)
    return c * e1 + s * e2, c * e1 - s * e2


def plane_to_line(n_cam: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Plane through the camera centre with normal n -> its image line in undistorted pixels,
    scaled to unit (a, b) and signed like n (positive where n . ray > 0)."""
    a = n_cam[0] / camera.fx
    b = n_cam[1] / camera.fy
    c = n_cam[2] - a * camera.cx - b * camera.cy
    return np.array([a, b, c]) / np.hypot(a, b)


def silhouette_lines(
    geom: InstrumentGeometry, camera: CameraModel, radius_m: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(line_left, line_right, n_left, n_right) of the cylinder of `radius_m` (default the shaft).
    Left/right as seen looking along the projected axis toward the tip."""
    r = geom.shaft_radius_m if radius_m is None else radius_m
    n1, n2 = tangent_normals(geom.p_tip_cam_m, geom.axis_cam, r)
    l1, l2 = plane_to_line(n1, camera), plane_to_line(n2, camera)
    g = projected_axis_direction(geom, camera)
    # inward normal of the left line points to the right of g (u right, v down)
    if g[0] * l1[1] - g[1] * l1[0] > 0:
        return l1, l2, n1, n2
    return l2, l1, n2, n1


def projected_axis_direction(geom: InstrumentGeometry, camera: CameraModel) -> np.ndarray:
    """Unit image direction (undistorted pixels) in which the axis runs toward the tip, taken at the
    junction (or at the visible axis point nearest to it when the junction is behind the camera)."""
    s0 = geom.s_junction
    p0 = geom.point(s0)
    if p0[2] < 1e-3:  # junction behind the camera: use the closest visible axis point
        p0 = geom.point(clip_axis_to_front(geom.p_tip_cam_m, geom.axis_cam, geom.s_proximal, geom.s_junction, 1e-3)[1])
    d = geom.axis_cam
    # derivative of the projection along d (always defined for z > 0)
    dx = (d[:2] * p0[2] - p0[:2] * d[2]) / p0[2] ** 2
    g = np.array([dx[0] * camera.fx, dx[1] * camera.fy])
    n = np.hypot(*g)
    if n < 1e-12:  # axis through the camera centre's line of sight: any direction will do
        return np.array([0.0, -1.0])
    return g / n


def clip_axis_to_front(
    p_axis_cam_m: np.ndarray, axis_cam: np.ndarray, s_lo: float, s_hi: float, z_near_m: float
) -> tuple[float, float]:
    """Clip the axis interval [s_lo, s_hi] (points p_axis + s axis) to z >= z_near_m in the camera
    frame; the result has lo >= hi when nothing is left."""
    z0, dz = p_axis_cam_m[2], axis_cam[2]
    if abs(dz) < 1e-12:
        return (s_lo, s_hi) if z0 >= z_near_m else (1.0, 0.0)
    s_z = (z_near_m - z0) / dz
    return (max(s_lo, s_z), s_hi) if dz > 0 else (s_lo, min(s_hi, s_z))


def _cylinder_hit(rays, p_axis, d, radius):
    """Nearest forward intersection with an infinite cylinder: (t, s, disc) per ray; t is the
    grazing parameter where the ray misses (disc < 0)."""
    rd = rays @ d
    r_perp = rays - rd[:, None] * d
    a_perp = p_axis - np.dot(p_axis, d) * d
    qa = np.einsum("ij,ij->i", r_perp, r_perp)
    qb = -(r_perp @ a_perp)
    qc = float(a_perp @ a_perp) - radius * radius
    disc = qb * qb - qa * qc
    qa = np.maximum(qa, 1e-30)
    t = (-qb - np.sqrt(np.maximum(disc, 0.0))) / qa
    s = t * rd - float(p_axis @ d)
    return t, s, disc


def cast_instrument(rays: np.ndarray, geom: InstrumentGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hit of rays (N, 3) from the camera centre (any length) on the instrument.
    Returns (part (N,) int8 with PART_*, t (N,) ray parameter, normal (N, 3) unit, camera frame)."""
    d, tip = geom.axis_cam, geom.p_tip_cam_m
    n = rays.shape[0]
    best_t = np.full(n, np.inf)
    part = np.zeros(n, np.int8)
    # shaft cylinder
    t, s, disc = _cylinder_hit(rays, tip, d, geom.shaft_radius_m)
    ok = (disc >= 0) & (t > 0) & (s <= geom.s_junction) & (s >= geom.s_proximal)
    best_t = np.where(ok, t, best_t)
    part[ok] = PART_SHAFT
    # distal end face of the shaft (annulus facing distally; its inner part is hidden by the jaws)
    rd = rays @ d
    pj = geom.point(geom.s_junction)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_face = np.where(np.abs(rd) > 1e-12, float(pj @ d) / rd, np.inf)
    q = rays * t_face[:, None] - pj
    ok = (t_face > 0) & (np.einsum("ij,ij->i", q, q) <= geom.shaft_radius_m**2) & (t_face < best_t)
    best_t = np.where(ok, t_face, best_t)
    part[ok] = PART_END_FACE
    # jaws: cylinder up to one jaw radius from the tip, closed by a hemisphere reaching the tip
    rj = geom.jaw_radius_m
    t, s, disc = _cylinder_hit(rays, tip, d, rj)
    ok = (disc >= 0) & (t > 0) & (s >= geom.s_junction) & (s <= -rj) & (t < best_t)
    best_t = np.where(ok, t, best_t)
    part[ok] = PART_JAWS
    c = geom.point(-rj)
    rr = np.einsum("ij,ij->i", rays, rays)
    b = rays @ c
    disc = b * b - rr * (float(c @ c) - rj * rj)
    t = (b - np.sqrt(np.maximum(disc, 0.0))) / rr
    ok = (disc >= 0) & (t > 0) & (t < best_t)
    best_t = np.where(ok, t, best_t)
    part[ok] = PART_JAW_TIP
    # normals
    p = rays * np.where(np.isfinite(best_t), best_t, 0.0)[:, None]
    rel = p - tip
    radial = rel - (rel @ d)[:, None] * d
    normal = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
    normal[part == PART_END_FACE] = d
    sel = part == PART_JAW_TIP
    normal[sel] = (p[sel] - c) / rj
    return part, best_t, normal


def cylinder_shading_hits(rays: np.ndarray, p_axis: np.ndarray, d: np.ndarray, radius: float):
    """For the analytic band: (points (N, 3), unit normals (N, 3), s (N,)) on an infinite cylinder,
    using the grazing point for rays that miss so that edge pixels still get a shade."""
    t, s, _ = _cylinder_hit(rays, p_axis, d, radius)
    p = rays * t[:, None]
    rel = p - p_axis
    radial = rel - (rel @ d)[:, None] * d
    normal = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
    return p, normal, s
