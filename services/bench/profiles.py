"""Error profiles: how hard the bench's motion-dependent error sources are.

A profile is a nested dict of scenario overrides, applied above the built-in defaults and
below a scenario file's explicit fields and `--set` (see `scenario.load_scenario`). `clean`
is the bench's static error models alone (no motion sources: today's draws for a seed);
`paper` sizes every motion source to the reference paper's bench and its sensors' data
sheets (docs/bench.md traces each number); `harsh` doubles every motion source of `paper`.
The estimators are never told which profile produced a session.

Each section is a dict of scenario fields, merged like a scenario file; `render` is the pixel
tier's camera and episodes (the measurement tier ignores it).
"""

from __future__ import annotations

import copy
from typing import Any

DEFAULT_PROFILE = "paper"

# The camera above the phantom: optical axis 15 deg from vertical, looking back at the tip
# from the distal side, 0.117 m from the neutral tip along its axis. The neutral shaft (28.6 deg
# from vertical) is then seen about 44 deg off the line of sight, 81 mm from the camera
# centre (tangent planes ~3.6 deg apart), and tilts toward the camera bring junction rays
# under the 1 - (d.u)^2 >= 0.45 conditioning limit.
_CAMERA_ABOVE = {"camera_rpy_deg": (180.0, 15.0, 0.0), "camera_distance_m": 0.117}

_PAPER: dict[str, Any] = {
    "motion": dict(_CAMERA_ABOVE),
    "vision": {
        "exposure_ms": 20.0,
        "edge_width_px": 2.0,
        "junction_blur_bias": 0.5,
        "junction_blur_sd": 0.5,
        "junction_speed_px_per_px": 0.4,
        "plane_speed_deg_per_px": 0.01,
        "range_growth_per_10mm": 0.2,
        "range_growth_per_10deg": 0.2,
        "gate_quality_weight": 1.0,
        "metric_scale_per_px": 0.0,
        "dropout_rate_per_min": 1.5,
        "dropout_s": (0.5, 10.0),
        "dropout_junction_only_frac": 0.3,
        "junction_across_mm": 0.3,
    },
    "tof": {
        "integration_ms": 10.0,
        "beam_fov_deg": 25.0,
        "surface_relief_mm": 1.0,
        "surface_corr_mm": 15.0,
        "pose_corr_spread": 2.0,
    },
    "accel": {
        "vibration_mps2_per_mps": 2.0,
        "vibration_hz": 15.0,
        "compliance_deg_per_mps2": 0.05,
    },
}

# The pixel tier's camera as built and its episodes (services/bench/render/effects.py; docs/bench.md,
# "Pixel tier in motion"): `harsh` about doubles every motion and episode source of `paper`.
_RENDER_PAPER: dict[str, Any] = {
    "exposure_ms": 16.0,
    "lens_error_sd_frac": 0.002,
    "lens_k1_error_sd": 0.004,
    "shaft_tilt_sd_deg": 0.10,
    "occluder_rate_per_min": 1.0,
    "occluder_duration_s": (1.0, 5.0),
    "smoke_rate_per_min": 0.5,
    "smoke_duration_s": (3.0, 10.0),
    "glare_rate_per_min": 1.0,
    "glare_duration_s": (0.5, 3.0),
}
_RENDER_HARSH: dict[str, Any] = {
    "exposure_ms": 33.0,
    "lens_error_sd_frac": 0.004,
    "lens_k1_error_sd": 0.008,
    "shaft_tilt_sd_deg": 0.20,
    "occluder_rate_per_min": 2.0,
    "occluder_duration_s": (1.0, 10.0),
    "smoke_rate_per_min": 1.0,
    "smoke_duration_s": (3.0, 10.0),
    "glare_rate_per_min": 2.0,
    "glare_duration_s": (0.5, 6.0),
}
_PAPER["render"] = _RENDER_PAPER

# Every motion source about twice `paper` (the geometry stays the paper's bench).
_DOUBLED = {
    "vision": (
        "exposure_ms",
        "junction_blur_sd",
        "junction_speed_px_per_px",
        "plane_speed_deg_per_px",
        "range_growth_per_10mm",
        "range_growth_per_10deg",
        "dropout_rate_per_min",
        "junction_across_mm",
    ),
    "tof": ("integration_ms", "surface_relief_mm"),
    "accel": ("vibration_mps2_per_mps", "compliance_deg_per_mps2"),
}


def _harsh() -> dict[str, Any]:
    out = copy.deepcopy(_PAPER)
    for section, keys in _DOUBLED.items():
        for k in keys:
            out[section][k] = 2.0 * out[section][k]
    out["vision"]["edge_width_px"] = 0.5 * _PAPER["vision"]["edge_width_px"]  # blur counts twice as much
    out["vision"]["gate_quality_weight"] = 0.5  # the gate follows quality less closely
    out["tof"]["pose_corr_spread"] = 3.0
    out["render"] = copy.deepcopy(_RENDER_HARSH)
    return out


PROFILES: dict[str, dict[str, Any]] = {"clean": {}, "paper": _PAPER, "harsh": _harsh()}


def profile_overrides(name: str) -> dict[str, Any]:
    """A deep copy of the named profile's scenario overrides; ValueError for an unknown name."""
    if name not in PROFILES:
        raise ValueError(f"unknown profile {name!r}; choose from {', '.join(PROFILES)}")
    return copy.deepcopy(PROFILES[name])
