"""Drawing the instrument (and occluders) into the undistorted canvas of a `Scene`.

The long shaft is drawn only inside a band around its silhouette strip (one run of pixels per
canvas row or column), with analytic edge coverage; the jaws and the junction are cast with
4x4 supersampling inside their small bounding box.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import ndtr

from services.bench.render.geometry import (
    PART_END_FACE,
    PART_JAW_TIP,
    PART_JAWS,
    PART_SHAFT,
    InstrumentGeometry,
    cast_instrument,
    clip_axis_to_front,
    cylinder_shading_hits,
    silhouette_lines,
)
from services.bench.render.scene import Scene

Z_NEAR_M = 0.005
BAND_MARGIN_PX = 2.0
SUPERSAMPLE = 4
JAW_GROOVE_M = 0.12e-3
MAX_DEFOCUS_PX = 8.0
BLOOD_RGB = np.array([0.38, 0.04, 0.06])
TISSUE_FLAP_RGB = np.array([0.80, 0.42, 0.40])


@dataclass(frozen=True)
class Material:
    albedo: np.ndarray  # (3,) RGB
    specular: float
    shininess: float


def shade(points, normals, rays, mat: Material, light, ambient: float, albedo=None, axis=None) -> np.ndarray:
    """Lambert + Blinn-Phong under a point light (camera frame, metres) -> RGB (N, 3) float32. With a
    cylinder `axis`, the half vector is taken across the axis, as for a lamp elongated along the
    shaft: the highlight is then a line running along the cylinder wherever the light is."""
    v = -rays / np.linalg.norm(rays, axis=1, keepdims=True)
    to_l = light - points
    to_l /= np.maximum(np.linalg.norm(to_l, axis=1, keepdims=True), 1e-12)
    ndl = np.clip(np.einsum("ij,ij->i", normals, to_l), 0.0, 1.0)
    hv = to_l + v
    if axis is not None:
        hv -= (hv @ axis)[:, None] * axis
    hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-12)
    ndh = np.clip(np.einsum("ij,ij->i", normals, hv), 0.0, 1.0)
    alb = mat.albedo[None, :] if albedo is None else albedo
    rgb = alb * (ambient + (1.0 - ambient) * ndl)[:, None] + (mat.specular * ndh**mat.shininess)[:, None]
    return rgb.astype(np.float32)


def _axis_px(scene: Scene, p: np.ndarray) -> np.ndarray:
    """Undistorted pixel of a camera-frame point (z > 0); within scene.max_shift_px of its image pixel."""
    c = scene.camera
    return np.array([c.fx * p[0] / p[2] + c.cx, c.fy * p[1] / p[2] + c.cy])


def defocus_sigma_px(z_m, defocus) -> np.ndarray:
    """Extra Gaussian defocus [px] at depth z [m] for defocus = (focus distance [m], sigma [px] per
    dioptre of focus error), capped at MAX_DEFOCUS_PX; zero without defocus."""
    if defocus is None or defocus[1] <= 0:
        return np.zeros_like(np.asarray(z_m, float))
    focus_m, per_dioptre = defocus
    return np.minimum(per_dioptre * np.abs(1.0 / np.asarray(z_m, float) - 1.0 / focus_m), MAX_DEFOCUS_PX)


def draw_cylinder_band(
    canvas,
    scene: Scene,
    p_axis,
    d,
    radius,
    s_lo,
    s_hi,
    lines,
    mat: Material,
    light,
    ambient,
    coverage_out=None,
    defocus=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Composite the cylinder piece s in [s_lo, s_hi] (axis point p_axis + s d, camera frame) over the
    canvas in place, edges from `lines` (left, right; undistorted pixels). Optionally max-accumulate
    its coverage into `coverage_out` (H, W). With `defocus` (see defocus_sigma_px), the long edges
    are the Gaussian-blurred step of the local depth's sigma, still centred on the lines.
    Returns the (rows, cols) of the pixels it drew."""
    s_lo_v, s_hi_v = clip_axis_to_front(p_axis, d, s_lo, s_hi, Z_NEAR_M)
    if s_lo_v >= s_hi_v:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    hc, wc = canvas.shape[:2]
    e0, e1 = p_axis + s_lo_v * d, p_axis + s_hi_v * d
    q0, q1 = _axis_px(scene, e0), _axis_px(scene, e1)
    sig_max = float(np.max(defocus_sigma_px(np.array([e0[2], e1[2]]), defocus)))
    margin = BAND_MARGIN_PX + 3.0 * sig_max
    r_px = radius * max(scene.camera.fx, scene.camera.fy) / min(e0[2], e1[2]) + 3.0 + scene.max_shift_px + 3 * sig_max
    g = q1 - q0
    rows = abs(g[1]) >= abs(g[0])
    major_n, minor_n = (hc, wc) if rows else (wc, hc)
    k = 1 if rows else 0
    m0 = max(0, int(np.floor(min(q0[k], q1[k]) - r_px)))
    m1 = min(major_n - 1, int(np.ceil(max(q0[k], q1[k]) + r_px)))
    if m0 > m1:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    major = np.arange(m0, m1 + 1, dtype=np.float64)
    lo = np.zeros_like(major)
    hi = np.full_like(major, minor_n - 1.0)
    cl = [np.asarray(ln, float) for ln in lines]
    for line in cl:
        a_min = line[0] if rows else line[1]
        if abs(a_min) < 0.2:  # steep against the scan: bound it loosely, as a half-plane
            a_maj = line[1] if rows else line[0]
            rhs = -margin - scene.max_shift_px - a_maj * major - line[2]
            if a_min > 1e-9:
                lo = np.maximum(lo, rhs / a_min)
            elif a_min < -1e-9:
                hi = np.minimum(hi, rhs / a_min)
            else:
                hi = np.where(rhs > 0, -1.0, hi)
            continue
        pos = _line_in_image(scene, line, rows, major)  # where the (distorted) line crosses each scan
        if a_min > 0:
            lo = np.maximum(lo, pos - (margin + 1.0) / a_min)
        else:
            hi = np.minimum(hi, pos - (margin + 1.0) / a_min)
    lo, hi = np.floor(lo).astype(np.int64), np.ceil(hi).astype(np.int64)
    width = int((hi - lo + 1).max())
    if width <= 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    minor = lo[:, None] + np.arange(width)[None, :]
    sel = minor <= hi[:, None]
    minor = minor[sel]
    major_i = np.broadcast_to(major.astype(np.int64)[:, None], sel.shape)[sel]
    ii, jj = (major_i, minor) if rows else (minor, major_i)
    u, v = scene.u_und[ii, jj], scene.v_und[ii, jj]
    dist = np.minimum(cl[0][0] * u + cl[0][1] * v + cl[0][2], cl[1][0] * u + cl[1][1] * v + cl[1][2])
    keep = dist > -0.5 - 3.0 * sig_max
    ii, jj, dist = ii[keep], jj[keep], dist[keep]
    rays = scene.pixel_rays(ii, jj)
    p, normal, s = cylinder_shading_hits(rays, p_axis, d, radius)
    if sig_max > 0:  # box pixel (variance 1/12) convolved with the defocus at the silhouette's depth
        cov = ndtr(dist / np.sqrt(defocus_sigma_px(p[:, 2], defocus) ** 2 + 1.0 / 12.0))
    else:
        cov = np.clip(0.5 + dist, 0.0, 1.0)
    # soft axial ends: metres of axis per pixel at each visible end
    for s_end, sign in ((s_hi, 1.0), (s_lo, -1.0)):
        if s_lo_v <= s_end <= s_hi_v:
            pe = p_axis + s_end * d
            pe2 = p_axis + (s_end - sign * 1e-3) * d
            dpx = np.linalg.norm(_axis_px(scene, pe) - _axis_px(scene, pe2))
            ds = 1e-3 / max(dpx, 1e-6)
            cov = cov * np.clip(0.5 + sign * (s_end - s) / ds, 0.0, 1.0)
        else:
            cov = cov * (sign * (s_end - s) >= 0)
    keep = cov > 0
    ii, jj, cov = ii[keep], jj[keep], cov[keep].astype(np.float32)
    rgb = shade(p[keep], normal[keep], rays[keep], mat, light, ambient, axis=d) * scene.gain_dn[ii, jj][:, None]
    bg = canvas[ii, jj]
    canvas[ii, jj] = bg + cov[:, None] * (rgb - bg)
    if coverage_out is not None:
        coverage_out[ii, jj] = np.maximum(coverage_out[ii, jj], cov)
    return ii, jj


def _line_in_image(scene: Scene, line: np.ndarray, rows: bool, major: np.ndarray) -> np.ndarray:
    """Minor coordinate (column if rows, else row) where an undistorted-pixel line, drawn through the
    lens distortion, crosses each major coordinate (image pixels); to about 0.1 px."""
    a, b, c = line
    a_min, a_maj = (a, b) if rows else (b, a)
    if not scene.distorted:
        return (-a_maj * major - c) / a_min
    pad = 3.0 * scene.max_shift_px + 8.0
    m_und = np.linspace(major[0] - pad, major[-1] + pad, max(8, int((major[-1] - major[0] + 2 * pad) / 4.0)))
    n_und = (-a_maj * m_und - c) / a_min
    u, v = (n_und, m_und) if rows else (m_und, n_und)
    cam = scene.camera
    xy = cam.distort_normalized(np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy], -1))
    ud, vd = xy[:, 0] * cam.fx + cam.cx, xy[:, 1] * cam.fy + cam.cy
    md, nd = (vd, ud) if rows else (ud, vd)
    order = np.argsort(md)
    return np.interp(major, md[order], nd[order])


def draw_jaws_region(
    canvas, scene: Scene, geom: InstrumentGeometry, y_tool_cam, shaft_mat: Material, jaw_mat: Material, light, ambient
) -> None:
    """Cast the junction and the jaws in their bounding box, in place: one ray per pixel, and
    SUPERSAMPLE^2 rays in pixels where the hit part changes next door. The box's background is the
    floor, so it replaces whatever the band drew there. Returns the box (rows, cols slices), if any."""
    r = geom.shaft_radius_m
    s_vals = np.array([geom.s_junction - 2 * r, geom.s_junction, -geom.jaw_radius_m, 0.0])
    d = geom.axis_cam
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = r * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)
    pts = (geom.point(s_vals)[:, None, :] + ring[None]).reshape(-1, 3)
    pts = pts[pts[:, 2] >= Z_NEAR_M]
    if len(pts) == 0:
        return None
    px = scene.camera.project(pts, distort=scene.distorted)
    hc, wc = canvas.shape[:2]
    j0, j1 = max(0, int(np.floor(px[:, 0].min())) - 2), min(wc - 1, int(np.ceil(px[:, 0].max())) + 2)
    i0, i1 = max(0, int(np.floor(px[:, 1].min())) - 2), min(hc - 1, int(np.ceil(px[:, 1].max())) + 2)
    if j0 > j1 or i0 > i1:
        return None
    bh, bw = i1 - i0 + 1, j1 - j0 + 1
    ii, jj = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
    ii, jj = ii.reshape(-1), jj.reshape(-1)
    bg = scene.floor_dn[ii, jj]
    gain = scene.gain_dn[ii, jj]
    rgb, label = _cast_and_shade(
        scene.pixel_rays(ii, jj), bg, gain, geom, y_tool_cam, shaft_mat, jaw_mat, light, ambient
    )
    lab = label.reshape(bh, bw)
    edge = np.zeros((bh, bw), bool)
    edge[1:] |= lab[1:] != lab[:-1]
    edge[:-1] |= lab[1:] != lab[:-1]
    edge[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    edge[:, :-1] |= lab[:, 1:] != lab[:, :-1]
    e = np.flatnonzero(edge.reshape(-1))
    if len(e):
        ss = SUPERSAMPLE
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ov, ou = (a.reshape(-1) for a in np.meshgrid(off, off, indexing="ij"))
        sv = (ii[e, None] + ov[None, :]).reshape(-1)
        su = (jj[e, None] + ou[None, :]).reshape(-1)
        sub, _ = _cast_and_shade(
            scene.subpixel_rays(sv, su),
            np.repeat(bg[e], ss * ss, axis=0),
            np.repeat(gain[e], ss * ss),
            geom,
            y_tool_cam,
            shaft_mat,
            jaw_mat,
            light,
            ambient,
        )
        rgb[e] = sub.reshape(len(e), ss * ss, 3).mean(axis=1)
    canvas[i0 : i1 + 1, j0 : j1 + 1] = rgb.reshape(bh, bw, 3)
    return slice(i0, i1 + 1), slice(j0, j1 + 1)


def _cast_and_shade(rays, bg, gain, geom: InstrumentGeometry, y_tool_cam, shaft_mat, jaw_mat, light, ambient):
    """Colour (N, 3) float32 [DN] of rays (background `bg` [DN] where they miss, `gain` (N,) DN per unit
    radiance) and a label (N,) int8 of what
    they hit (part, with the jaw groove as its own label) for edge detection."""
    part, t, normal = cast_instrument(rays, geom)
    out = bg.astype(np.float32, copy=True)
    label = part.copy()
    hit = part != 0
    if not np.any(hit):
        return out, label
    p = rays[hit] * t[hit, None]
    n_hit, r_hit, part_hit = normal[hit], rays[hit], part[hit]
    rgb = np.empty((len(p), 3), np.float32)
    is_shaft = (part_hit == PART_SHAFT) | (part_hit == PART_END_FACE)
    if np.any(is_shaft):
        sel = part_hit == PART_SHAFT
        rgb[sel] = shade(p[sel], n_hit[sel], r_hit[sel], shaft_mat, light, ambient, axis=geom.axis_cam)
        sel = part_hit == PART_END_FACE
        rgb[sel] = shade(p[sel], n_hit[sel], r_hit[sel], shaft_mat, light, ambient)
    is_jaw = ~is_shaft
    if np.any(is_jaw):
        pj = p[is_jaw]
        # the gap between the two jaw halves: a dark groove in the tool's x-z plane
        groove = np.abs((pj - geom.p_tip_cam_m) @ y_tool_cam) < JAW_GROOVE_M
        alb = np.where(groove[:, None], jaw_mat.albedo * 0.15, jaw_mat.albedo)
        rgb[is_jaw] = shade(pj, n_hit[is_jaw], r_hit[is_jaw], jaw_mat, light, ambient, albedo=alb)
        rgb[is_jaw] *= np.where(groove, 0.3, 1.0)[:, None]
        lab_hit = label[hit]
        lab_hit[is_jaw] += 10 * groove
        label[hit] = lab_hit
    out[hit] = rgb * gain[hit, None]
    return out, label


def draw_blob(canvas, coverage_out, scene: Scene, geom: InstrumentGeometry, rng: np.random.Generator) -> None:
    """A soft tissue-coloured or bloody blob (a flap, a drop on the lens) over part of the shaft."""
    s = rng.uniform(geom.s_junction - 0.06, geom.s_junction)
    p = geom.point(s)
    if p[2] < Z_NEAR_M:
        p = geom.point(geom.s_junction)
    centre = _axis_px(scene, p) + rng.normal(0.0, 15.0, 2)
    axes = rng.uniform(12, 60, 2)
    hc, wc = canvas.shape[:2]
    r = int(np.ceil(axes.max())) + 2
    x0, y0 = max(0, int(centre[0]) - r), max(0, int(centre[1]) - r)
    x1, y1 = min(wc, int(centre[0]) + r + 1), min(hc, int(centre[1]) + r + 1)
    if x0 >= x1 or y0 >= y1:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    c16 = (int((centre[0] - x0) * 16), int((centre[1] - y0) * 16))
    cv2.ellipse(mask, c16, (int(axes[0] * 16), int(axes[1] * 16)), float(rng.uniform(0, 180)), 0, 360, 255, -1,
                cv2.LINE_AA, 4)  # fmt: skip
    h, w = mask.shape
    sl = np.s_[y0:y1, x0:x1]
    alpha = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (0, 0), 1.2)
    # blood or a tissue flap, domed (brighter where it is thick) and mottled
    base = BLOOD_RGB if rng.random() < 0.4 else TISSUE_FLAP_RGB
    colour = (base * rng.uniform(0.8, 1.1, 3)).astype(np.float32)
    dome = cv2.GaussianBlur(alpha, (0, 0), max(2.0, 0.25 * float(axes.min())))
    mottle = cv2.GaussianBlur(rng.random((h, w), dtype=np.float32), (0, 0), 3.0)
    shade_f = (0.55 + 0.45 * dome * (0.85 + 0.3 * mottle))[..., None]
    canvas[sl] += alpha[..., None] * (colour * shade_f * scene.gain_dn[sl][..., None] - canvas[sl])
    coverage_out[sl] = np.maximum(coverage_out[sl], alpha)


def random_second_instrument(scene: Scene, geom: InstrumentGeometry, rng: np.random.Generator):
    """A second shaft crossing in front of the instrument: (geometry, (line_left, line_right)) or None."""
    s = rng.uniform(geom.s_junction - 0.05, geom.s_junction)
    p = geom.point(s)
    if p[2] < 0.03:
        return None
    q = p * rng.uniform(0.6, 0.85)  # on the same line of sight, nearer the camera
    view = q / np.linalg.norm(q)
    a = rng.normal(size=3)
    a -= (a @ view) * view
    a /= np.linalg.norm(a)
    tip = q + a * rng.uniform(0.01, 0.04)
    g2 = InstrumentGeometry(tip, a, float(rng.uniform(0.0025, 0.005)), 0.001, 0.0, 0.5)
    try:
        lines = silhouette_lines(g2, scene.camera)
    except ValueError:
        return None
    return g2, lines[:2]


def instrument_masks(
    scene: Scene, geom: InstrumentGeometry, line_l, line_r, candidates=None
) -> tuple[np.ndarray, np.ndarray]:
    """(shaft mask, jaws mask) (H, W) bool over image pixels, by casting each pixel centre's ray.
    `candidates`: (rows, cols) known to contain every instrument pixel (default: the whole frame)."""
    h, w = scene.u_und.shape
    if candidates is None:
        iy, ix = np.nonzero(np.ones((h, w), bool))
    else:
        iy, ix = candidates
    u, v = scene.u_und[iy, ix], scene.v_und[iy, ix]
    inside = (line_l[0] * u + line_l[1] * v + line_l[2] >= 0) & (line_r[0] * u + line_r[1] * v + line_r[2] >= 0)
    iy, ix = iy[inside], ix[inside]
    shaft = np.zeros((h, w), bool)
    jaws = np.zeros((h, w), bool)
    if len(iy):
        part, _, _ = cast_instrument(scene.pixel_rays(iy, ix), geom)
        shaft[iy, ix] = (part == PART_SHAFT) | (part == PART_END_FACE)
        jaws[iy, ix] = (part == PART_JAWS) | (part == PART_JAW_TIP)
    return shaft, jaws
