"""Per-scene precomputation for the pixel renderer: per-pixel rays through the lens distortion,
the lit phantom floor with its procedural tissue texture, the vignetting/exposure gain and the
noise table. Built once per (camera, scene parameters) and reused for every frame.

Frames are drawn directly on the distorted image grid: each pixel's centre carries its exact
undistorted coordinates (u_und, v_und) and camera ray, so geometry is evaluated exactly where
the pixel looks and no resampling (remap) of the frame is needed.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.special import ndtri

from tiplog.geometry.camera import CameraModel

TEXEL_MIN_M = 0.25e-3
TEXTURE_MAX_TEXELS = 2048
FAT_RGB = np.array([0.90, 0.74, 0.58], np.float32)
DEEP_RGB = np.array([0.62, 0.20, 0.22], np.float32)
VESSEL_RGB = np.array([0.50, 0.10, 0.14], np.float32)
BACKGROUND_RGB = np.array([0.06, 0.06, 0.07], np.float32)
SMOKE_RADIANCE = 0.85


class Scene:
    """Everything about a frame that does not depend on the instrument pose or on chance. Images here
    are in digital numbers (DN, 0-255 scale, float32) after exposure and vignetting."""

    def __init__(self, camera: CameraModel, params) -> None:
        self.camera = camera
        h, w = camera.height, camera.width
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        self.distorted = any(abs(k) > 0 for k in camera.dist)
        if self.distorted:
            und = camera.undistort_pixels(np.stack([uu, vv], -1))
            self.u_und, self.v_und = und[..., 0], und[..., 1]
        else:
            self.u_und, self.v_und = uu, vv
        # largest shift the distortion makes anywhere in the frame, to widen pixel searches
        self.max_shift_px = float(np.max(np.hypot(self.u_und - uu, self.v_und - vv))) + 1.0 if self.distorted else 0.0
        self.x_n = (self.u_und - camera.cx) / camera.fx
        self.y_n = (self.v_und - camera.cy) / camera.fy
        cos4 = 1.0 / (1.0 + self.x_n**2 + self.y_n**2) ** 2
        vig = 1.0 - params.vignetting * (1.0 - cos4)
        # radiance -> digital numbers: locked exposure times vignetting, folded into everything drawn
        self.gain_dn = (255.0 * params.exposure * vig).astype(np.float32)
        self.floor_dn = self._floor(params) * self.gain_dn[..., None]
        self.smoke_dn = np.repeat(SMOKE_RADIANCE * self.gain_dn[..., None], 3, axis=2)  # haze lit by the lamp
        # 8-bit uniform draws -> unit-variance normal deviates (256-level inverse CDF table)
        z = ndtri((np.arange(256) + 0.5) / 256.0)
        self.normal_lut = (z / z.std()).astype(np.float32)
        # shot + read noise standard deviation [DN] by (rounded) signal level [DN]
        level = np.arange(256, dtype=np.float64)
        self.sigma_lut = np.sqrt(params.read_noise_dn**2 + level / params.electrons_per_dn).astype(np.float32)

    def pixel_rays(self, ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        """Integer image pixels -> camera-frame rays (x, y, 1) (N, 3) through their centres, float64."""
        x, y = self.x_n[ii, jj], self.y_n[ii, jj]
        return np.stack([x, y, np.ones_like(x)], -1)

    def subpixel_rays(self, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Image points at any position (distorted pixels, within the frame) -> rays (N, 3), by
        bilinear interpolation of the per-pixel rays (the distortion is smooth on a pixel's scale)."""
        h, w = self.x_n.shape
        v = np.clip(v, 0.0, h - 1.0)
        u = np.clip(u, 0.0, w - 1.0)
        i0 = np.minimum(v.astype(np.int64), h - 2)
        j0 = np.minimum(u.astype(np.int64), w - 2)
        fv, fu = v - i0, u - j0
        out = np.ones(v.shape + (3,))
        for k, m in enumerate((self.x_n, self.y_n)):
            top = m[i0, j0] + fu * (m[i0, j0 + 1] - m[i0, j0])
            bot = m[i0 + 1, j0] + fu * (m[i0 + 1, j0 + 1] - m[i0 + 1, j0])
            out[..., k] = top + fv * (bot - top)
        return out

    # floor ---------------------------------------------------------------------------
    def _floor(self, params) -> np.ndarray:
        n = np.asarray(params.floor_normal_cam, float)
        n = n / np.linalg.norm(n)
        rays = np.stack([self.x_n, self.y_n, np.ones_like(self.x_n)], -1)
        rn = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -params.floor_distance_m / rn
        valid = np.isfinite(t) & (t > 0)
        t = np.where(valid, t, 0.0)
        p = rays * t[..., None]
        e1 = np.cross(n, [0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        tx, ty = p @ e1, p @ e2
        x0, x1 = tx[valid].min(), tx[valid].max()
        y0, y1 = ty[valid].min(), ty[valid].max()
        texel = max(TEXEL_MIN_M, (x1 - x0) / TEXTURE_MAX_TEXELS, (y1 - y0) / TEXTURE_MAX_TEXELS)
        tw, th = int((x1 - x0) / texel) + 2, int((y1 - y0) / texel) + 2
        tex = tissue_texture(th, tw, texel, params.floor_colour, params.texture_strength, params.texture_seed)
        mx = ((tx - x0) / texel).astype(np.float32)
        my = ((ty - y0) / texel).astype(np.float32)
        albedo = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        # point light: Lambert with inverse-square fall-off, normalised at the image centre's floor point
        light = np.asarray(params.light_pos_cam_m, float)
        to_l = light - p
        dist_l = np.linalg.norm(to_l, axis=-1)
        lam = np.clip((to_l @ n) / np.maximum(dist_l, 1e-9), 0.0, 1.0)
        c = self.camera.height // 2, self.camera.width // 2
        ref = dist_l[c] if valid[c] else params.floor_distance_m
        irr = params.ambient + (1.0 - params.ambient) * lam * (ref / np.maximum(dist_l, 1e-6)) ** 2
        # a faint wet sheen (Blinn-Phong) modulated by the texture's low frequencies
        v = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        hv = to_l / np.maximum(dist_l, 1e-9)[..., None] + v
        hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
        spec = 0.10 * np.clip(hv @ n, 0.0, 1.0) ** 40
        rgb = albedo * irr[..., None].astype(np.float32) + spec[..., None].astype(np.float32)
        rgb[~valid] = BACKGROUND_RGB
        return np.ascontiguousarray(rgb, dtype=np.float32)


def _octave(rng: np.random.Generator, h: int, w: int, feature_texels: float) -> np.ndarray:
    gh, gw = max(2, int(h / feature_texels) + 2), max(2, int(w / feature_texels) + 2)
    g = rng.random((gh, gw), dtype=np.float32)
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)


def tissue_texture(h: int, w: int, texel_m: float, colour, strength: float, seed: int) -> np.ndarray:
    """Procedural tissue albedo (h, w, 3) float32 in [0, 1]: low-frequency colour and brightness
    variation, fatty and deeper patches, branching vessels and fine speckle."""
    rng = np.random.default_rng(seed)
    base = np.asarray(colour, np.float32)
    mm = 1e-3 / texel_m
    bright = 0.55 * _octave(rng, h, w, 40 * mm) + 0.3 * _octave(rng, h, w, 12 * mm) + 0.15 * _octave(rng, h, w, 4 * mm)
    tex = np.empty((h, w, 3), np.float32)
    tex[:] = base
    fat = 0.6 * np.clip((_octave(rng, h, w, 25 * mm) - 0.68) * 4.0, 0.0, 1.0)[..., None]
    deep = np.clip((_octave(rng, h, w, 18 * mm) - 0.5) * 2.0, 0.0, 1.0)[..., None]
    tex += fat * (FAT_RGB - tex)
    tex += 0.55 * deep * (DEEP_RGB - tex)
    tex *= (0.78 + 0.44 * bright)[..., None]
    # vessels: smooth random walks, some branching, drawn anti-aliased and softened
    vessels = np.zeros((h, w), np.uint8)
    n_vessels = int(np.clip(h * w / (70 * mm) ** 2, 4, 25))
    for _ in range(n_vessels):
        _draw_vessel(vessels, rng, mm, depth=0, width_mm=rng.uniform(0.3, 0.9))
    alpha = cv2.GaussianBlur(vessels.astype(np.float32) / 255.0, (0, 0), max(0.6, 0.15 * mm))[..., None]
    tex += 0.5 * alpha * (VESSEL_RGB - tex)
    speckle = cv2.GaussianBlur(rng.random((h, w), dtype=np.float32), (0, 0), 0.8) - 0.5
    tex *= (1.0 + 0.25 * speckle)[..., None]
    out = base + strength * (tex - base)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _draw_vessel(
    img: np.ndarray, rng: np.random.Generator, mm: float, depth: int, width_mm: float, start=None, heading=None
) -> None:
    h, w = img.shape
    p = np.array(start if start is not None else (rng.uniform(0, w), rng.uniform(0, h)))
    a = heading if heading is not None else rng.uniform(0, 2 * np.pi)
    steps = int(rng.integers(20, 60))
    pts = [p.copy()]
    for _ in range(steps):
        a += rng.normal(0.0, 0.12)
        p = p + 1.5 * mm * np.array([np.cos(a), np.sin(a)])
        pts.append(p.copy())
        if depth < 2 and rng.random() < 0.04:
            _draw_vessel(img, rng, mm, depth + 1, width_mm * 0.6, p, a + rng.choice([-1, 1]) * rng.uniform(0.4, 1.0))
    thick = max(1, int(round(width_mm * mm)))
    poly = (np.array(pts) * 16).astype(np.int32)  # 4 fractional bits
    cv2.polylines(img, [poly], False, int(rng.integers(90, 255)), thick, cv2.LINE_AA, shift=4)
