"""The rule-based labeler: the shaft's two silhouette lines and its junction from one camera
frame, deterministic and pure (image and camera in, geometry out).

Steps (paper, "Markerless Shaft Geometry from Vision"): a coarse dark blob on a subsampled grid
says where the shaft is; in undistorted coordinates each silhouette edge is found at its
gradient maximum with sub-pixel precision along profiles across it, and a trimmed line fit gives
each line; the junction is the gradient maximum (dark shaft -> bright jaws) along the centre
line. The same lines and junction give the labeler's mask on any grid (for the gate's IoU and as
the network's training label).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.vision import edges
from tiplog.geometry.camera import CameraModel

# The junction is looked for along lines this far from the centre line, in half widths of the
# shaft: outside the jaws (radius 1.7 of 2.59 mm, 0.66) and clear of the blurred edges, where
# the dark shaft ends against the background at its end rim, whatever the jaws' shading.
JUNCTION_LINES = (0.78, 0.83, 0.88)
JUNCTION_RIM_FRACTION = float(np.sqrt(1.0 - np.mean(JUNCTION_LINES) ** 2))


class LabelerParams(BaseModel):
    """Tuning of the labeler (pixel units are full-resolution image pixels)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    channel: Literal["red", "gray"] = "red"
    coarse_step: int = Field(4, ge=1, le=16, description="subsampling of the coarse blob search")
    dark_threshold: float = Field(60.0, gt=0.0, lt=255.0, description="coarse shaft: channel below this")
    min_blob_cells: int = Field(40, ge=1, description="smallest coarse blob taken for a shaft")
    edge_window_px: float = Field(6.0, gt=1.0, le=30.0, description="half length of an edge profile")
    min_edge_step: float = Field(12.0, gt=0.0, description="weakest edge step accepted, grey levels per px")
    keep_fraction: float = Field(0.8, gt=0.3, le=1.0, description="trimmed line fit: points kept per pass")
    min_edge_points: int = Field(8, ge=4)
    junction_min_step: float = Field(10.0, gt=0.0, description="weakest junction step, grey levels per px")


@dataclass
class ShaftLabel:
    """Lines (3,) in undistorted pixels, positive inside; left/right as seen looking toward the
    tip. junction_px (2,) undistorted pixels (NaN when not visible); direction (2,) unit image
    direction toward the tip; residual_px: RMS of the kept edge points about their lines."""

    ok: bool
    reason: str = ""
    line_left: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    line_right: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    junction_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    junction_visible: bool = False
    direction: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    residual_px: float = float("nan")
    centre_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))  # middle of the visible shaft
    edge_points: tuple[np.ndarray, np.ndarray] | None = None

    def centre_line(self) -> np.ndarray:
        """The midline (3,) between the two silhouette lines, undistorted pixels, (a, b) unit."""
        m = self.line_left - self.line_right
        return m / np.hypot(m[0], m[1])


def channel_image(img_rgb: np.ndarray, channel: str) -> np.ndarray:
    """The float32 (H, W) image the edges are found in."""
    if channel == "red":
        return img_rgb[:, :, 0].astype(np.float32)
    return (img_rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float32)


def lines_from_blob(
    img: np.ndarray,
    camera: CameraModel,
    img_step: float,
    img_offset: float,
    blob: edges.Blob,
    blob_step: float,
    window_px: float,
    min_step: float,
    keep_fraction: float,
    min_points: int,
    junction_min_step: float,
    junction_lines: tuple[float, ...] = JUNCTION_LINES,
) -> ShaftLabel:
    """Lines and junction refined in `img` (a dark shaft on brighter ground) around a coarse blob;
    the junction is looked for along lines `junction_lines` half widths either side of the centre
    line (a mask without the jaws, such as the network's, may use the middle)."""
    width = float(np.median(blob.s_hi - blob.s_lo)) + blob_step
    lo_pts, hi_pts = edges.edge_points(
        img, camera, img_step, img_offset, blob, blob_step, window_px, min_step, distal_margin_px=1.5 * width
    )
    if min(len(lo_pts), len(hi_pts)) < min_points:
        return ShaftLabel(False, "too_few_edge_points")
    line_lo, r_lo, _ = edges.fit_line(lo_pts, keep_fraction)
    line_hi, r_hi, _ = edges.fit_line(hi_pts, keep_fraction)
    line_lo = _inside_positive(line_lo, blob)
    line_hi = _inside_positive(line_hi, blob)
    # s grows to the right of the direction: the low-s edge is the left one
    lab = ShaftLabel(True, "", line_lo, line_hi, direction=blob.direction.copy())
    lab.residual_px = float(np.hypot(r_lo, r_hi) / np.sqrt(2.0))
    lab.edge_points = (lo_pts, hi_pts)
    m = lab.centre_line()
    mid_t = 0.5 * (blob.t_min + blob.t_max)
    q = blob.point(mid_t, 0.0)
    lab.centre_px = q - (m[:2] @ q + m[2]) * m[:2]
    if not blob.distal_at_border:
        j = _junction(img, camera, img_step, img_offset, blob, lab, width, junction_min_step, junction_lines)
        if j is not None:
            lab.junction_px = j
            lab.junction_visible = True
    return lab


def _inside_positive(line: np.ndarray, blob: edges.Blob) -> np.ndarray:
    """Flip a line's sign so that the blob's centre line lies on its positive side."""
    mid = blob.point(0.0, 0.5 * (blob.s_lo.mean() + blob.s_hi.mean()))
    return line if line[:2] @ mid + line[2] > 0 else -line


def _junction(
    img: np.ndarray,
    camera: CameraModel,
    img_step: float,
    img_offset: float,
    blob: edges.Blob,
    lab: ShaftLabel,
    width: float,
    min_step: float,
    lines: tuple[float, ...] = JUNCTION_LINES,
    sample_px: float = 0.5,
) -> np.ndarray | None:
    """Junction (2,) in undistorted pixels, on the centre line: the mean position of the strongest
    dark -> bright steps along lines on either side of the centre line (JUNCTION_LINES) near the
    blob's distal end. Those lines meet the end rim at rho_s * JUNCTION_RIM_FRACTION nearer the
    camera than the axis (tiplog.geometry.vision.junction_on_axis)."""
    m = lab.centre_line()
    g = np.array([m[1], -m[0]])
    if g @ blob.direction < 0:
        g = -g
    nrm = np.array([-g[1], g[0]])
    q0 = blob.centre - (m[:2] @ blob.centre + m[2]) * m[:2]  # blob centre onto the midline
    t_end = (blob.point(blob.t_max, 0.0) - q0) @ g
    q_end = q0 + t_end * g
    local = float(lab.line_left[:2] @ q_end + lab.line_left[2] + lab.line_right[:2] @ q_end + lab.line_right[2])
    half = 0.5 * (local if np.isfinite(local) and local > 0 else width)
    t = np.arange(t_end - 3.0 * width - 8.0, t_end + 1.5 * width + 8.0, sample_px)
    t_found = []
    for side in (-1.0, 1.0):
        s = side * np.asarray(lines) * half
        uv = q0 + t[None, :, None] * g + s[:, None, None] * nrm
        prof = edges.sample(img, edges.undist_to_grid(camera, uv, img_step, img_offset)).mean(0)
        d = np.zeros_like(prof)
        d[1:-1] = prof[2:] - prof[:-2]
        pos, peak = edges._subsample_peak(d[None, :])
        if peak[0] < 2.0 * min_step * sample_px or not (2 < pos[0] < len(d) - 3):
            return None
        t_found.append(t[0] + pos[0] * sample_px)
    if abs(t_found[0] - t_found[1]) > half:  # the two sides disagree: not a clean end
        return None
    return q0 + 0.5 * (t_found[0] + t_found[1]) * g


def label_frame(img_rgb: np.ndarray, camera: CameraModel, params: LabelerParams | None = None) -> ShaftLabel:
    """The labeler on one (H, W, 3) uint8 RGB frame of `camera`'s size."""
    p = params or LabelerParams()
    img = channel_image(img_rgb, p.channel)
    st = p.coarse_step
    off = (st - 1) / 2.0
    coarse = img[int(off) :: st, int(off) :: st] if st > 1 else img
    # cell centres of an integer-strided grid: offset floor((st-1)/2)
    off = float(int(off))
    mask = coarse < p.dark_threshold
    h, w = mask.shape
    uv = edges.grid_undistorted(camera, float(st), off, h, w)
    blob = edges.find_blob(_close(mask), uv, st, p.min_blob_cells)
    if isinstance(blob, str):
        return ShaftLabel(False, blob)
    return lines_from_blob(
        img, camera, 1.0, 0.0, blob, float(st), p.edge_window_px, p.min_edge_step, p.keep_fraction,
        p.min_edge_points, p.junction_min_step,
    )  # fmt: skip


def _close(mask: np.ndarray) -> np.ndarray:
    """Morphological closing (3x3) so that the shaft's specular stripe does not split it."""
    import cv2

    k = np.ones((3, 3), np.uint8)
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, k).astype(bool)


def label_mask(lab: ShaftLabel, uv_undist: np.ndarray) -> np.ndarray:
    """The label's shaft mask on a grid whose pixel centres have undistorted coordinates
    `uv_undist` (h, w, 2): inside both lines and proximal of the junction (when visible)."""
    if not lab.ok:
        return np.zeros(uv_undist.shape[:2], bool)
    x, y = uv_undist[..., 0], uv_undist[..., 1]
    inside = (lab.line_left[0] * x + lab.line_left[1] * y + lab.line_left[2] > 0) & (
        lab.line_right[0] * x + lab.line_right[1] * y + lab.line_right[2] > 0
    )
    if lab.junction_visible:
        inside &= (x - lab.junction_px[0]) * lab.direction[0] + (y - lab.junction_px[1]) * lab.direction[1] <= 0
    return inside
