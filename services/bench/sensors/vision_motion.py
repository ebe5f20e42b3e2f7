"""Motion terms of the measurement-tier vision model: what a moving shaft does to a frame.

The D405's colour sensor (OV9782) has a global shutter: every row is exposed over the same
interval, so a frame shows the shaft smeared along its image motion over the exposure and
never skewed row by row. From that:

- blur across a silhouette edge widens the edge and the gradient maximum scatters more
  (tangent-plane noise grows as the edge width sqrt(w0^2 + b^2) / w0);
- blur along the shaft smears the junction: the mask's distal end is the most distal
  position during the exposure, so the junction shifts distally by half the axial blur
  (`junction_blur_bias` = 0.5) and scatters with it;
- labeler and network disagree more on a moving shaft (errors per px/frame of image motion);
- away from the validated range of monocular reconstruction (near 140 mm insertion, tilt
  within 10 deg) every vision error grows;
- the consistency gate compares two estimates of one frame, so a frame's own motion error
  adds to the measures' rest spread (`gate_quality_weight`): the gate rejects mostly bad
  frames and passes some;
- correlated dropouts (another instrument crossing, smoke, glare, the tool leaving the
  field) blank whole frames, or only the junction, for 0.5-10 s.

Pure numpy; every draw comes from the generator passed in (a child of the vision stream's),
so a clean session's draws are what they were before these terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.bench.scenario import VisionConfig


def motion_enabled(v: VisionConfig) -> bool:
    """True when any motion source of the vision model is switched on."""
    return any(
        x > 0
        for x in (
            v.exposure_ms,
            v.junction_speed_px_per_px,
            v.plane_speed_deg_per_px,
            v.range_growth_per_10mm,
            v.range_growth_per_10deg,
            v.gate_quality_weight,
            v.dropout_rate_per_min,
            v.junction_across_mm,
        )
    )


@dataclass
class ImageMotion:
    """Per frame: the junction's blur vector over the exposure [px] split into the part along
    the shaft's image direction (signed, + distal) and across it, the image scale along the
    axis [px per m], and the junction's image motion per frame period [px]."""

    blur_axial_px: np.ndarray
    blur_across_px: np.ndarray
    px_per_m_axial: np.ndarray
    speed_px_per_frame: np.ndarray


def image_motion(
    project, J_minus: np.ndarray, J_plus: np.ndarray, J_c: np.ndarray, u_c: np.ndarray, speed: np.ndarray
) -> ImageMotion:
    """From the junction in the camera frame at the start and end of the exposure (n, 3), its
    centre J_c and the axis u_c (n, 3) [m]; `project` maps camera points to undistorted px."""
    blur = np.nan_to_num(project(J_plus) - project(J_minus))
    uv0 = project(J_c)
    axis_px = np.nan_to_num(project(J_c + 1e-3 * u_c) - uv0) * 1e3  # px per m along +u
    scale = np.linalg.norm(axis_px, axis=1)
    e = axis_px / np.maximum(scale, 1e-9)[:, None]
    along = (blur * e).sum(1)
    across = np.abs(blur[:, 0] * e[:, 1] - blur[:, 1] * e[:, 0])
    return ImageMotion(along, across, np.maximum(scale, 1.0), speed)


def range_growth(v: VisionConfig, depth_mm: np.ndarray, tilt_deg: np.ndarray) -> np.ndarray:
    """Error factor (>= 1) per frame outside the validated insertion depth and tilt."""
    lo, hi = v.validated_depth_mm
    out_mm = np.maximum(lo - depth_mm, 0.0) + np.maximum(depth_mm - hi, 0.0)
    out_deg = np.maximum(tilt_deg - v.validated_tilt_deg, 0.0)
    return 1.0 + v.range_growth_per_10mm * out_mm / 10.0 + v.range_growth_per_10deg * out_deg / 10.0


def edge_factor(v: VisionConfig, m: ImageMotion) -> np.ndarray:
    """Growth of the silhouette-edge noise with the blur across the edge."""
    return np.sqrt(1.0 + (m.blur_across_px / v.edge_width_px) ** 2)


def junction_axial_error_m(v: VisionConfig, m: ImageMotion, g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Junction displacement along the axis [m] from blur and image motion (bias + scatter),
    scaled by the range growth g."""
    b = np.abs(m.blur_axial_px)
    sd_px = np.hypot(v.junction_blur_sd * b, v.junction_speed_px_per_px * m.speed_px_per_frame)
    px = v.junction_blur_bias * b + rng.normal(size=len(b)) * sd_px
    return g * px / m.px_per_m_axial


def dropouts(
    v: VisionConfig, t_ns: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, list[tuple[float, float, str]]]:
    """(frame blanked (n,), junction hidden (n,), the bursts as (start_s, duration_s, kind)):
    bursts start as a Poisson process at dropout_rate_per_min, last log-uniform in dropout_s,
    and hide only the junction with probability dropout_junction_only_frac."""
    n = len(t_ns)
    blank, hide = np.zeros(n, bool), np.zeros(n, bool)
    bursts: list[tuple[float, float, str]] = []
    if n == 0 or v.dropout_rate_per_min <= 0:
        return blank, hide, bursts
    span_s = float(t_ns[-1]) * 1e-9
    k = rng.poisson(v.dropout_rate_per_min * span_s / 60.0)
    starts = np.sort(rng.uniform(0.0, span_s, k))
    lo, hi = np.log(v.dropout_s[0]), np.log(v.dropout_s[1])
    durs = np.exp(rng.uniform(lo, hi, k))
    junction_only = rng.random(k) < v.dropout_junction_only_frac
    ts = t_ns * 1e-9
    for s0, d, j in zip(starts, durs, junction_only, strict=True):
        m = (ts >= s0) & (ts < s0 + d)
        (hide if j else blank)[m] = True
        bursts.append((float(s0), float(d), "junction" if j else "frame"))
    return blank, hide, bursts


def gate_measure(z: np.ndarray, n: np.ndarray, weight: float) -> np.ndarray:
    """A consistency measure in units of its rest spread: the independent draw n (N(0,1)) with
    the frame's own motion error z (same units) added in quadrature, weighted. With weight 0
    (or z = 0, a frame at rest) this is |n|, the measure as drawn without the quality term."""
    if weight <= 0:
        return np.abs(n)
    return np.sqrt(n**2 + weight * z**2)
