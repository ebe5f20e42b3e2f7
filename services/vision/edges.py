"""Silhouette edges of a dark shaft, found the same way in a camera image (the labeler) and in
the network's mask (the gate's independent measure): a coarse blob gives where to look, each
edge is then located at its gradient maximum along profiles sampled in undistorted pixel
coordinates (so the edges are straight lines there), and a trimmed total-least-squares fit
gives each line.

Pixels: "distorted" are the image's own (u right, v down, origin at the top-left pixel's
centre); "undistorted" those of the ideal pinhole with the same K (tiplog.geometry.camera). A
grid is a subsampled image: grid pixel (i, j) sits at distorted (j * step + offset, i * step +
offset). Lines are (a, b, c) with a u + b v + c = 0 in undistorted pixels, (a, b) unit, positive
inside the shaft.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from tiplog.geometry.camera import CameraModel


@lru_cache(maxsize=16)
def grid_undistorted(camera: CameraModel, step: float, offset: float, h: int, w: int) -> np.ndarray:
    """Undistorted pixel coordinates (h, w, 2) of a grid's pixel centres (cached per camera)."""
    jj, ii = np.meshgrid(np.arange(w) * step + offset, np.arange(h) * step + offset)
    return camera.undistort_pixels(np.stack([jj, ii], -1)).astype(np.float64)


def undist_to_grid(camera: CameraModel, uv_undist: np.ndarray, step: float, offset: float) -> np.ndarray:
    """Undistorted pixels (..., 2) -> fractional grid coordinates (x, y) (..., 2) of a grid."""
    xy = np.stack([(uv_undist[..., 0] - camera.cx) / camera.fx, (uv_undist[..., 1] - camera.cy) / camera.fy], -1)
    d = camera.distort_normalized(xy)
    u = camera.fx * d[..., 0] + camera.cx
    v = camera.fy * d[..., 1] + camera.cy
    return np.stack([(u - offset) / step, (v - offset) / step], -1)


def sample(img: np.ndarray, grid_xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 (H, W) image at fractional coordinates (..., 2); border
    replicated."""
    shape = grid_xy.shape[:-1]
    flat = grid_xy.reshape(-1, 2).astype(np.float32)
    mx = np.ascontiguousarray(flat[:, 0]).reshape(1, -1)
    my = np.ascontiguousarray(flat[:, 1]).reshape(1, -1)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(shape)


@dataclass
class Blob:
    """The shaft blob in undistorted pixels: centre, unit direction toward the distal end, its
    extent [t_min, t_max] along it, per-station edge offsets (perpendicular coordinate s, positive
    to the right of the direction) and whether the distal / proximal ends touch the image border."""

    centre: np.ndarray
    direction: np.ndarray
    t_min: float
    t_max: float
    station_t: np.ndarray
    s_lo: np.ndarray
    s_hi: np.ndarray
    distal_at_border: bool
    proximal_at_border: bool

    @property
    def normal(self) -> np.ndarray:
        """Unit perpendicular, to the right of the direction (u right, v down)."""
        return np.array([-self.direction[1], self.direction[0]])

    def point(self, t: np.ndarray, s: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)[..., None]
        s = np.asarray(s, float)[..., None]
        return self.centre + t * self.direction + s * self.normal


def find_blob(
    mask: np.ndarray,
    uv_undist: np.ndarray,
    step: float,
    min_pixels: int,
    border_cells: int = 2,
    min_elongation: float = 3.0,
) -> Blob | str:
    """The largest connected component of a grid mask (h, w) bool as a Blob, or the reason
    there is none ('no_shaft': none, too small, or not at least `min_elongation` times longer
    than wide, by the standard deviations along and across it)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n < 2:
        return "no_shaft"
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < min_pixels:
        return "no_shaft"
    ii, jj = np.nonzero(labels == k)
    pts = uv_undist[ii, jj]
    c = pts.mean(0)
    cov = np.cov((pts - c).T)
    lam, vecs = np.linalg.eigh(cov)
    if lam[1] < min_elongation**2 * max(lam[0], 1e-9):  # a shaft is long and thin; shadows are not
        return "no_shaft"
    g = vecs[:, 1]
    t = (pts - c) @ g
    h, w = mask.shape
    at_border = (ii < border_cells) | (jj < border_cells) | (ii >= h - border_cells) | (jj >= w - border_cells)
    span = t.max() - t.min()
    near_hi = at_border & (t > t.max() - 0.15 * span)
    near_lo = at_border & (t < t.min() + 0.15 * span)
    if near_hi.any() and not near_lo.any():  # the blob leaves the image at its +g end: proximal
        g, t = -g, -t
        near_hi, near_lo = near_lo, near_hi
    elif near_hi.any() and near_lo.any() and g[1] < 0:  # both ends cut: any fixed choice
        g, t = -g, -t
        near_hi, near_lo = near_lo, near_hi
    nrm = np.array([-g[1], g[0]])
    s = (pts - c) @ nrm
    bin_px = max(2.0 * step, 6.0)
    edges = np.arange(t.min(), t.max() + bin_px, bin_px)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    nb = len(edges) - 1
    s_lo = np.full(nb, np.inf)
    s_hi = np.full(nb, -np.inf)
    np.minimum.at(s_lo, idx, s)
    np.maximum.at(s_hi, idx, s)
    counts = np.bincount(idx, minlength=nb)
    ok = counts >= 2
    return Blob(
        centre=c,
        direction=g,
        t_min=float(t.min()),
        t_max=float(t.max()),
        station_t=0.5 * (edges[:-1] + edges[1:])[ok],
        s_lo=s_lo[ok],
        s_hi=s_hi[ok],
        distal_at_border=bool(near_hi.any()),
        proximal_at_border=bool(near_lo.any()),
    )


def _subsample_peak(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the maximum of each row of d (m, k), refined by a parabola, and the maximum."""
    k = d.shape[1]
    i = np.clip(np.argmax(d, axis=1), 1, k - 2)
    r = np.arange(len(d))
    y0, y1, y2 = d[r, i - 1], d[r, i], d[r, i + 1]
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
    return i + np.clip(off, -0.5, 0.5), y1


def edge_points(
    img: np.ndarray,
    camera: CameraModel,
    img_step: float,
    img_offset: float,
    blob: Blob,
    blob_step: float,
    window_px: float,
    min_step: float,
    distal_margin_px: float,
    max_stations: int = 64,
    sample_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Edge points (k, 2) in undistorted pixels, found in `img` (a float32 grid of step `img_step`,
    offset `img_offset`; 1 and 0 for the camera image itself), on the low-s and high-s sides of the blob, each at
    the gradient maximum (dark inside -> bright outside) of a profile across the edge, with
    sub-sample precision; profiles whose step is weaker than `min_step` (image units) or whose
    maximum lies at the window's end are dropped. The last `distal_margin_px` before the blob's
    distal end are left out (the junction's rim curves there)."""
    keep = blob.station_t < blob.t_max - distal_margin_px
    t, lo, hi = blob.station_t[keep], blob.s_lo[keep], blob.s_hi[keep]
    if len(t) > max_stations:
        sel = np.linspace(0, len(t) - 1, max_stations).round().astype(int)
        t, lo, hi = t[sel], lo[sel], hi[sel]
    half = blob_step / 2.0  # a blob cell's centre is half a cell inside the edge
    k = int(np.ceil(window_px / sample_px))
    off = np.arange(-k, k + 1) * sample_px
    out = []
    for s0, sign in ((lo - half, -1.0), (hi + half, 1.0)):
        # profile outward (sign): offsets from s0 along +-normal; 3 parallel profiles averaged
        ss = s0[:, None] + sign * off[None, :]
        prof = 0.0
        for dt in (-1.0, 0.0, 1.0):
            uv = blob.point(np.broadcast_to(t[:, None] + dt, ss.shape), ss)
            prof = prof + sample(img, undist_to_grid(camera, uv, img_step, img_offset))
        prof = prof / 3.0
        d = np.zeros_like(prof)
        d[:, 1:-1] = prof[:, 2:] - prof[:, :-2]
        pos, peak = _subsample_peak(d)
        good = (peak >= 2.0 * min_step * sample_px) & (pos > 2) & (pos < d.shape[1] - 3)
        s_edge = s0 + sign * (pos - k) * sample_px
        out.append(blob.point(t[good], s_edge[good]))
    return out[0], out[1]


def fit_line(pts: np.ndarray, keep_fraction: float = 0.8, iterations: int = 2) -> tuple[np.ndarray, float, int]:
    """Trimmed total-least-squares line through points (k, 2): (a, b, c) with (a, b) unit, the RMS
    residual of the kept points [px] and their number. Each pass keeps the `keep_fraction` of
    points nearest the previous fit."""
    if len(pts) < 4:
        raise ValueError(f"a line fit needs at least 4 edge points (got {len(pts)})")
    use = np.ones(len(pts), bool)
    for it in range(iterations + 1):
        p = pts[use]
        c = p.mean(0)
        _, _, vt = np.linalg.svd(p - c, full_matrices=False)
        nrm = vt[1]
        line = np.array([nrm[0], nrm[1], -nrm @ c])
        r = np.abs(pts @ line[:2] + line[2])
        if it < iterations:
            use = r <= np.quantile(r, keep_fraction)
    kept = r[use]
    return line, float(np.sqrt(np.mean(kept**2))), int(use.sum())
