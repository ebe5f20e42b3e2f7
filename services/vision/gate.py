"""The consistency gate: a frame is trusted only when the labeler and the network agree (paper:
mask IoU >= 0.75, line direction < 0.5 deg, lateral < 1.5 px, junction < 4 px).

Lines are compared as the shaft's centre lines (the midline between the two silhouette lines),
in undistorted full-resolution pixels; the lateral offset is the network's centre line's
distance from the labeler's at the middle of the labeler's visible shaft.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.vision.labeler import ShaftLabel


class GateParams(BaseModel):
    """Thresholds of the consistency gate and the junction's conditioning test."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    min_mask_iou: float = Field(0.75, ge=0.0, le=1.0)
    max_line_angle_deg: float = Field(0.5, gt=0.0, le=90.0)
    max_lateral_px: float = Field(1.5, gt=0.0)
    max_junction_px: float = Field(4.0, gt=0.0)
    min_junction_sin2: float = Field(0.45, ge=0.0, le=1.0, description="reject the junction when 1 - (d.u)^2 is below")


@dataclass
class GateMeasures:
    mask_iou: float
    line_angle_deg: float
    lateral_px: float
    junction_diff_px: float  # NaN when neither saw the junction

    def reasons(self, p: GateParams) -> list[str]:
        """The gate's failures, in the order the paper lists them (empty: accepted)."""
        out = []
        if not self.mask_iou >= p.min_mask_iou:
            out.append("gate:mask_iou")
        if not self.line_angle_deg < p.max_line_angle_deg:
            out.append("gate:line_angle")
        if not self.lateral_px < p.max_lateral_px:
            out.append("gate:lateral")
        if not (np.isnan(self.junction_diff_px) or self.junction_diff_px < p.max_junction_px):
            out.append("gate:junction")
        return out


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks of one grid (1 when both are empty)."""
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 1.0


def measures(lab: ShaftLabel, net: ShaftLabel, lab_mask: np.ndarray, net_mask: np.ndarray) -> GateMeasures:
    """The four gate measures between the labeler's and the network's results."""
    iou = mask_iou(lab_mask, net_mask)
    if not (lab.ok and net.ok):
        return GateMeasures(iou, float("inf"), float("inf"), float("inf"))
    m1, m2 = lab.centre_line(), net.centre_line()
    cosang = abs(float(m1[:2] @ m2[:2]))
    angle = float(np.degrees(np.arccos(min(1.0, cosang))))
    q = lab.centre_px
    lateral = abs(float(m2[:2] @ q + m2[2]))
    if lab.junction_visible and net.junction_visible:
        jd = float(np.linalg.norm(lab.junction_px - net.junction_px))
    elif lab.junction_visible or net.junction_visible:
        jd = float("inf")
    else:
        jd = float("nan")
    return GateMeasures(iou, angle, lateral, jd)
