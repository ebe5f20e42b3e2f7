"""The vision tip offset: junction-derived tip minus the robot's tip, along the shaft.

For each accepted vision frame with a visible junction inside a static pose: the robot's shaft
axis is mapped into the camera frame through the hand-eye transform and the junction ray meets
it at J (the point of the axis closest to the ray), mapped back to base. This is the geometry
the estimator's tip update uses (the junction p - L_j u must lie on the ray); the axis seen by
vision is not used, because its distance from the camera (P0) is ill-conditioned. The
junction-derived tip is J + junction_proximal_m u, and the offset is its distance ahead of the
robot's tip along u, averaged per pose (median over the pose's frames) and then over poses.
A fusion run subtracts it (`vision_tip_offset_m` in the calibration file). Because it is fitted
through the same hand-eye transform the estimator uses, it also absorbs that transform's error
along the shaft at the working pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.calibration.fits import require
from tiplog.geometry import vision as vg

FIT = "vision tip offset"


@dataclass(frozen=True)
class VisionOffsetResult:
    vision_tip_offset_m: float
    per_pose_mm: np.ndarray  # (k,) per-pose medians of the offset
    heldout_mm: float  # RMS of each pose's median against the mean of the other poses
    frames: int
    poses: int


def junction_offsets_m(
    junction_ray: np.ndarray,
    R_base_tool: np.ndarray,
    p_tip_base_m: np.ndarray,
    T_base_camera: np.ndarray,
    junction_proximal_m: float,
    min_conditioning: float = 0.45,
) -> np.ndarray:
    """Per frame (n,): (junction-derived tip - robot tip) . u [m]; NaN where the ray is
    ill-conditioned against the axis (1 - (d.u)^2 < min_conditioning)."""
    A = np.asarray(T_base_camera, float)[:3, :3]
    c = np.asarray(T_base_camera, float)[:3, 3]
    u_base = np.asarray(R_base_tool, float)[:, :, 2]
    u_cam = u_base @ A
    tip_cam = (np.asarray(p_tip_base_m, float) - c) @ A
    _, J_cam, cond = vg.ray_axis_intersection(junction_ray, tip_cam, u_cam)
    J_base = J_cam @ A.T + c
    off = np.einsum("ij,ij->i", J_base + junction_proximal_m * u_base - p_tip_base_m, u_base)
    return np.where(cond >= min_conditioning, off, np.nan)


def fit_vision_offset(offsets_m_per_pose: list[np.ndarray], min_frames: int = 3) -> VisionOffsetResult:
    """Mean over k >= 3 poses of each pose's median offset [m]; poses with fewer than
    min_frames usable frames are dropped."""
    med = np.array([np.nanmedian(o) for o in offsets_m_per_pose if np.sum(np.isfinite(o)) >= min_frames])
    frames = int(sum(np.sum(np.isfinite(o)) for o in offsets_m_per_pose))
    require(
        len(med) >= 3,
        FIT,
        f"needs at least 3 static poses with {min_frames}+ accepted frames showing the junction (got {len(med)})",
    )
    held = np.array([med[i] - np.delete(med, i).mean() for i in range(len(med))])
    return VisionOffsetResult(float(med.mean()), med * 1e3, float(np.sqrt(np.mean(held**2)) * 1e3), frames, len(med))
