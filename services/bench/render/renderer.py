"""Pixel-tier renderer of the bench camera: a dark instrument shaft with metallic jaws over a
textured tissue phantom, as the RealSense D405 colour stream would see it (RGB uint8).

Geometry is exact: the shaft's long silhouette edges are drawn with analytic coverage
clip(0.5 + d, 0, 1) of the signed pixel distance d to the tangent lines (the images of the
planes through the camera centre tangent to the shaft cylinder), so the 50 % level and the
gradient maximum of every edge lie on the analytic line before blur and noise; the jaws and the
junction are ray cast, 4x4 supersampled where the surface hit changes between pixels.
Pipeline per frame, float32 digital numbers (exposure is locked: a fixed gain, folded with the
vignetting into everything drawn):
  precomputed lit floor -> shaft band, jaws -> occluder (blob or second instrument, by chance)
  -> smoke (by chance) -> Gaussian defocus (global) -> shot + read noise -> uint8.
Lens distortion is exact rather than resampled: the frame is drawn on the distorted pixel grid
and each pixel's geometry is evaluated at its exact undistorted coordinates (precomputed rays).
The floor, its texture, the per-pixel rays and the gain maps are built once per (camera, scene
fields) and cached, so a frame costs only the instrument and the image-wide filters.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import partial
from typing import Annotated

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from services.bench.render.effects import RenderSession, crossing_instrument, draw_glare, smoke_alpha
from services.bench.render.geometry import InstrumentGeometry, silhouette_lines
from services.bench.render.instrument import (
    Material,
    defocus_sigma_px,
    draw_blob,
    draw_cylinder_band,
    draw_jaws_region,
    instrument_masks,
    random_second_instrument,
)
from services.bench.render.scene import Scene
from tiplog.geometry.camera import CameraModel

Unit = Annotated[float, Field(ge=0.0, le=1.0)]
RGB = tuple[Unit, Unit, Unit]
PosSeconds = Annotated[float, Field(gt=0.0, le=600.0)]

# fields that change the precomputed scene (floor, texture, gain); the others act per frame
SCENE_FIELDS = (
    "floor_normal_cam", "floor_distance_m", "floor_colour", "texture_seed", "texture_strength",
    "light_pos_cam_m", "ambient", "vignetting", "exposure", "read_noise_dn", "electrons_per_dn",
)  # fmt: skip


class RenderParams(BaseModel):
    """Scene, instrument, optics and sensor of the pixel renderer (SI units unless named)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # instrument
    shaft_radius_m: float = Field(0.00259, gt=0.0005, le=0.01)
    shaft_length_m: float = Field(
        0.45, gt=0.02, le=2.0, description="shaft proximal of the junction (to the trocar and beyond)"
    )
    junction_from_tip_mm: float = Field(
        12.0, ge=2.0, le=40.0, description="shaft end / jaws start, proximal of the tip"
    )
    jaw_radius_m: float = Field(0.0017, gt=0.0002, le=0.01)
    shaft_albedo: RGB = (0.045, 0.045, 0.05)
    shaft_specular: float = Field(0.35, ge=0.0, le=2.0)
    shaft_shininess: float = Field(40.0, ge=1.0, le=2000.0)
    jaw_albedo: RGB = (0.38, 0.39, 0.41)
    jaw_specular: float = Field(0.9, ge=0.0, le=2.0)
    jaw_shininess: float = Field(18.0, ge=1.0, le=2000.0)
    # phantom floor: plane n . X + floor_distance_m = 0 in the camera frame, n toward the camera
    floor_normal_cam: tuple[float, float, float] = (0.0, 0.0, -1.0)
    floor_distance_m: float = Field(0.32, gt=0.02, le=5.0)
    floor_colour: RGB = (0.80, 0.46, 0.43)
    texture_seed: int = Field(0, ge=0)
    texture_strength: Unit = 1.0
    # light (a point lamp near the camera) and optics
    light_pos_cam_m: tuple[float, float, float] = (0.04, -0.08, 0.0)
    ambient: Unit = 0.3
    blur_sigma_px: float = Field(0.8, ge=0.0, le=4.0, description="global defocus, Gaussian sigma")
    focus_distance_m: float = Field(0.25, gt=0.02, le=5.0)
    defocus_px_per_dioptre: float = Field(
        0.0,
        ge=0.0,
        le=5.0,
        description="extra depth-dependent blur of the instrument: sigma per dioptre of focus error",
    )
    vignetting: Unit = 0.35
    # sensor: exposure is locked (a fixed gain, no auto exposure)
    exposure: float = Field(1.0, gt=0.0, le=8.0)
    sensor_noise: bool = True
    read_noise_dn: float = Field(1.2, ge=0.0, le=50.0)
    electrons_per_dn: float = Field(8.0, ge=0.1, le=1e4, description="shot noise: variance = signal_dn / this")
    # chance events, drawn per frame from the caller's generator
    smoke_probability: Unit = 0.05
    smoke_density: Unit = 0.45
    occlusion_probability: Unit = 0.05
    # a real bench camera in motion (services/bench/render/effects.py; off by default)
    exposure_ms: float = Field(
        0.0, ge=0.0, le=66.7, description="locked exposure time (global shutter); 0: drawn at one instant"
    )
    exposure_subframe_px: float = Field(
        1.0, gt=0.05, le=10.0, description="image motion between the sub-frame renders averaged over the exposure"
    )
    exposure_subframes_max: int = Field(9, ge=1, le=33)
    lens_error_sd_frac: float = Field(
        0.0, ge=0.0, le=0.02, description="factory calibration residual: fx, fy, cx, cy (in units of fx, fy)"
    )
    lens_k1_error_sd: float = Field(0.0, ge=0.0, le=0.05, description="residual of the radial distortion k1")
    shaft_tilt_sd_deg: float = Field(
        0.0, ge=0.0, le=2.0, description="visible shaft against the tool axis (straightness, mount)"
    )
    occluder_rate_per_min: float = Field(0.0, ge=0.0, le=60.0, description="episodes of a second instrument")
    occluder_duration_s: tuple[PosSeconds, PosSeconds] = (1.0, 5.0)
    smoke_rate_per_min: float = Field(0.0, ge=0.0, le=60.0, description="episodes of drifting smoke")
    smoke_duration_s: tuple[PosSeconds, PosSeconds] = (3.0, 10.0)
    glare_rate_per_min: float = Field(0.0, ge=0.0, le=60.0, description="episodes of specular glare")
    glare_duration_s: tuple[PosSeconds, PosSeconds] = (0.5, 3.0)

    @model_validator(mode="after")
    def _check(self) -> RenderParams:
        if self.jaw_radius_m >= self.shaft_radius_m:
            raise ValueError(
                f"jaw_radius_m ({self.jaw_radius_m}) must be smaller than shaft_radius_m ({self.shaft_radius_m})"
            )
        if self.jaw_radius_m * 1e3 >= self.junction_from_tip_mm:
            raise ValueError("junction_from_tip_mm must exceed the jaw radius")
        n = np.asarray(self.floor_normal_cam, float)
        if not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"floor_normal_cam must be a non-zero vector (got {self.floor_normal_cam})")
        if n[2] >= 0:
            raise ValueError(f"floor_normal_cam must face the camera (negative z), got {self.floor_normal_cam}")
        if not all(np.isfinite(self.light_pos_cam_m)):
            raise ValueError("light_pos_cam_m must be finite")
        for kind in ("occluder", "smoke", "glare"):
            lo, hi = getattr(self, f"{kind}_duration_s")
            if lo > hi:
                raise ValueError(f"{kind}_duration_s must run from min to max (got ({lo:g}, {hi:g}))")
        return self


_SCENES: OrderedDict = OrderedDict()
_SCENES_LOCK = threading.Lock()
_SCENES_MAX = 4


def get_scene(camera: CameraModel, params: RenderParams) -> Scene:
    """The precomputed scene for this camera and these scene fields (built on first use, cached)."""
    key = (camera, tuple(getattr(params, f) for f in SCENE_FIELDS))
    with _SCENES_LOCK:
        scene = _SCENES.get(key)
        if scene is not None:
            _SCENES.move_to_end(key)
            return scene
    scene = Scene(camera, params)
    with _SCENES_LOCK:
        _SCENES[key] = scene
        while len(_SCENES) > _SCENES_MAX:
            _SCENES.popitem(last=False)
    return scene


def render_frame(
    camera: CameraModel,
    T_camera_tool: np.ndarray,
    params: RenderParams,
    rng: np.random.Generator,
    truth_out: dict | None = None,
    *,
    t_s: float | None = None,
    session: RenderSession | None = None,
) -> np.ndarray:
    """One colour frame (H, W, 3) uint8 RGB of the instrument at T_camera_tool (4x4; tool origin at
    the tip, z along the shaft, distal), or over the exposure: (M, 4, 4), M odd, poses evenly spaced
    over the exposure interval with the frame's instant in the middle (global shutter: every pixel
    integrates the same interval), drawn as the mean of sub-frame renders. `session` (a
    RenderSession) draws through its lens, with its shaft tilt and its episodes under way at the
    session time t_s [s]. With `truth_out`, fills it with the exact geometry at the middle pose (of
    the drawn shaft, in the lens the frame is drawn through):
      line_left, line_right: (3,) lines a*u + b*v + c = 0 in undistorted pixels, (a, b) unit, positive
        inside the shaft; n_left_cam, n_right_cam: the tangent-plane normals (camera frame);
      junction_px, tip_px: (2,) undistorted pixels of the axis points at the junction and the tip
        (junction_px_distorted, tip_px_distorted: the same in image pixels; NaN behind the camera);
      p_tip_cam_m, p_junction_cam_m, axis_cam: (3,) camera frame;
      mask: (H, W) bool, image pixels whose centre ray first meets the shaft (proximal of the junction);
      jaws_mask: (H, W) bool, the same for the jaws; occluder_mask: (H, W) bool, pixels covered >= 50 %
        by the occluder (in front of the instrument); occlusion: "none" | "blob" | "instrument";
      smoke: bool; glare: bool; subframes: sub-frame renders averaged."""
    T_all = np.asarray(T_camera_tool, float)
    if T_all.ndim == 2:
        T_all = T_all[None]
    if T_all.ndim != 3 or T_all.shape[1:] != (4, 4) or len(T_all) % 2 == 0:
        raise ValueError(f"T_camera_tool must be 4x4 or (M, 4, 4) with M odd (got shape {T_all.shape})")
    lens = camera if session is None else session.lens
    if session is not None:
        T_all = T_all @ session.T_tool_shaft
    scene = get_scene(lens, params)
    light = np.asarray(params.light_pos_cam_m, float)
    shaft_mat = Material(np.asarray(params.shaft_albedo), params.shaft_specular, params.shaft_shininess)
    jaw_mat = Material(np.asarray(params.jaw_albedo), params.jaw_specular, params.jaw_shininess)
    draw = partial(_draw_instrument, scene=scene, params=params, shaft_mat=shaft_mat, jaw_mat=jaw_mat, light=light)

    subs = _exposure_subset(T_all, lens, params)
    canvas = scene.floor_dn.copy()
    if len(subs) == 1:
        geom, band, box = draw(canvas, subs[0])
    else:  # mean of sub-frames: each drawn on the floor, its difference added where it drew
        floor = scene.floor_dn.reshape(-1, 3)
        out = canvas.reshape(-1, 3)
        work = scene.floor_dn.copy()
        flat_w = work.reshape(-1, 3)
        w = canvas.shape[1]
        for i, T in enumerate(subs):
            g_i, band_i, box_i = draw(work, T)
            if i == len(subs) // 2:
                geom, band, box = g_i, band_i, box_i
            idx = band_i[0] * w + band_i[1]
            if box_i is not None:
                bi, bj = np.mgrid[box_i[0], box_i[1]]
                idx = np.unique(np.concatenate([idx, (bi * w + bj).ravel()]))
            out[idx] += (flat_w[idx] - floor[idx]) / len(subs)
            flat_w[idx] = floor[idx]
    line_l, line_r, n_l, n_r = silhouette_lines(geom, lens)

    occlusion, occ_cov = "none", None
    if rng.random() < params.occlusion_probability:
        occ_cov = np.zeros(canvas.shape[:2], np.float32)
        other = random_second_instrument(scene, geom, rng) if rng.random() < 0.5 else None
        if other is not None:
            occlusion = "instrument"
            g2, lines2 = other
            mat2 = Material(np.full(3, rng.uniform(0.05, 0.25)), 0.6, 40.0)
            draw_cylinder_band(canvas, scene, g2.p_tip_cam_m, g2.axis_cam, g2.shaft_radius_m, g2.s_proximal, 0.0,
                               lines2, mat2, light, params.ambient, coverage_out=occ_cov)  # fmt: skip
        if occlusion == "none" or not occ_cov.any():
            occlusion = "blob"
            draw_blob(canvas, occ_cov, scene, geom, rng)
    smoke = bool(rng.random() < params.smoke_probability)
    if smoke:
        _add_smoke(canvas, scene, rng, params.smoke_density)
    glare = False
    for ep in session.active(t_s) if session is not None else ():
        if ep.kind == "occluder":
            other = crossing_instrument(scene, geom, ep, t_s)
            if other is not None:
                occ_cov = np.zeros(canvas.shape[:2], np.float32) if occ_cov is None else occ_cov
                g2, lines2 = other
                mat2 = Material(np.full(3, 0.08 + 0.15 * (ep.seed % 7) / 6.0), 0.6, 40.0)
                draw_cylinder_band(canvas, scene, g2.p_tip_cam_m, g2.axis_cam, g2.shaft_radius_m, g2.s_proximal,
                                   0.0, lines2, mat2, light, params.ambient, coverage_out=occ_cov)  # fmt: skip
                occlusion = "instrument"
        elif ep.kind == "smoke":
            alpha = smoke_alpha(canvas.shape[:2], ep, t_s, params.smoke_density)
            canvas[:] = cv2.blendLinear(canvas, scene.smoke_dn, 1.0 - alpha, alpha)
            smoke = True
        else:
            draw_glare(canvas, scene, geom, ep, t_s)
            glare = True

    if params.blur_sigma_px > 0:
        canvas = cv2.GaussianBlur(canvas, (0, 0), params.blur_sigma_px)
    dn = canvas  # digital numbers >= 0: exposure (locked) and vignetting are folded in by the scene
    if params.sensor_noise:
        h, w = lens.height, lens.width
        draws = np.frombuffer(rng.bytes(h * w * 3), np.uint8).reshape(h, w, 3)
        z = cv2.LUT(draws, scene.normal_lut)
        sigma = cv2.LUT(cv2.convertScaleAbs(dn), scene.sigma_lut)
        cv2.accumulateProduct(sigma, z, dn)
        dn = cv2.max(dn, 0.0)
    img = cv2.convertScaleAbs(dn)  # rounds and saturates at 255 (dn >= 0 here)

    if truth_out is not None:
        rows, cols = band
        if box is not None:  # the jaws and the junction may reach beyond the band
            bi, bj = np.mgrid[box[0], box[1]]
            rows, cols = np.concatenate([rows, bi.ravel()]), np.concatenate([cols, bj.ravel()])
        _fill_truth(truth_out, scene, lens, geom, (rows, cols), line_l, line_r, n_l, n_r, occlusion, occ_cov, smoke)
        truth_out.update(glare=glare, subframes=len(subs))
    return img


def _draw_instrument(canvas, T_camera_tool, *, scene, params, shaft_mat, jaw_mat, light):
    """Draw the instrument at one pose in place: (geometry, band pixels (rows, cols), the box the jaws
    and their defocus touched or None)."""
    geom = InstrumentGeometry.from_pose(
        T_camera_tool,
        params.shaft_radius_m,
        params.jaw_radius_m,
        params.junction_from_tip_mm * 1e-3,
        params.shaft_length_m,
    )
    line_l, line_r, _, _ = silhouette_lines(geom, scene.camera)
    defocus = (params.focus_distance_m, params.defocus_px_per_dioptre) if params.defocus_px_per_dioptre > 0 else None
    band = draw_cylinder_band(
        canvas,
        scene,
        geom.p_tip_cam_m,
        geom.axis_cam,
        geom.shaft_radius_m,
        geom.s_proximal,
        geom.s_junction,
        (line_l, line_r),
        shaft_mat,
        light,
        params.ambient,
        defocus=defocus,
    )
    box = draw_jaws_region(canvas, scene, geom, T_camera_tool[:3, 1], shaft_mat, jaw_mat, light, params.ambient)
    if box is not None:
        box = _defocus_box(canvas, box, float(defocus_sigma_px(geom.point(geom.s_junction)[2], defocus)))
    return geom, band, box


def _exposure_subset(T_all: np.ndarray, lens: CameraModel, params: RenderParams) -> list[np.ndarray]:
    """The poses to draw over the exposure: enough that the junction, the tip and the shaft 40 mm
    proximal move at most about exposure_subframe_px between two of them (odd in number, the middle
    one always among them; one at rest or without an exposure time)."""
    m = len(T_all)
    mid = T_all[m // 2]
    if m == 1 or params.exposure_ms <= 0:
        return [mid]
    j = params.junction_from_tip_mm * 1e-3
    pts_tool = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, -j, 1.0], [0.0, 0.0, -j - 0.04, 1.0]])
    ends = np.stack([(T_all[0] @ pts_tool.T).T[:, :3], (T_all[-1] @ pts_tool.T).T[:, :3]])
    if np.any(ends[..., 2] < 0.01):
        return [mid]
    px = lens.project(ends.reshape(-1, 3), distort=False).reshape(2, -1, 2)
    travel = float(np.max(np.linalg.norm(px[1] - px[0], axis=-1)))
    n = int(np.clip(np.ceil(travel / params.exposure_subframe_px) + 1, 1, min(m, params.exposure_subframes_max)))
    n = n + 1 if n % 2 == 0 and n < m else n - (n % 2 == 0)
    if n <= 1:
        return [mid]
    return [T_all[i] for i in np.round(np.linspace(0, m - 1, n)).astype(int)]


def _defocus_box(canvas: np.ndarray, box: tuple[slice, slice], sigma_px: float) -> tuple[slice, slice]:
    """Blur the jaws' box (and a margin) by the defocus at the junction's depth, in place; the box
    with its margin."""
    if sigma_px < 0.1:
        return box
    m = int(np.ceil(3 * sigma_px))
    h, w = canvas.shape[:2]
    i0, i1 = max(0, box[0].start - m), min(h, box[0].stop + m)
    j0, j1 = max(0, box[1].start - m), min(w, box[1].stop + m)
    canvas[i0:i1, j0:j1] = cv2.GaussianBlur(canvas[i0:i1, j0:j1], (0, 0), sigma_px)
    return slice(i0, i1), slice(j0, j1)


def _add_smoke(canvas: np.ndarray, scene: Scene, rng: np.random.Generator, density: float) -> None:
    """Semi-transparent low-frequency haze over the whole view, in place (canvas in DN): opacity from a
    coarse random field, smoothly upsampled; one blending pass."""
    h, w = canvas.shape[:2]
    sh, sw = max(2, h // 8), max(2, w // 8)
    field = cv2.resize(rng.random((6, 10), dtype=np.float32), (sw, sh), interpolation=cv2.INTER_CUBIC)
    alpha = density * np.clip(0.35 + 1.2 * (field - 0.5), 0.0, 1.0)
    alpha = cv2.resize(alpha, (w, h), interpolation=cv2.INTER_LINEAR)
    canvas[:] = cv2.blendLinear(canvas, scene.smoke_dn, 1.0 - alpha, alpha)


def _fill_truth(
    out: dict,
    scene: Scene,
    camera: CameraModel,
    geom: InstrumentGeometry,
    candidates,
    line_l,
    line_r,
    n_l,
    n_r,
    occlusion: str,
    occ_cov,
    smoke: bool,
) -> None:
    p_j = geom.point(geom.s_junction)
    pts = np.stack([p_j, geom.p_tip_cam_m])
    und = camera.project(pts, distort=False)
    dis = camera.project(pts, distort=True)
    mask, jaws = instrument_masks(scene, geom, line_l, line_r, candidates)
    if occ_cov is not None:
        occ = occ_cov >= 0.5
    else:
        occ = np.zeros((camera.height, camera.width), bool)
    out.update(
        line_left=line_l, line_right=line_r, n_left_cam=n_l, n_right_cam=n_r,
        junction_px=und[0], tip_px=und[1], junction_px_distorted=dis[0], tip_px_distorted=dis[1],
        p_tip_cam_m=geom.p_tip_cam_m.copy(), p_junction_cam_m=p_j, axis_cam=geom.axis_cam.copy(),
        mask=mask, jaws_mask=jaws, occluder_mask=occ, occlusion=occlusion, smoke=smoke,
    )  # fmt: skip
