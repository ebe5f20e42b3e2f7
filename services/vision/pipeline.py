"""One frame through the whole method: labeler, network, consistency gate, tangent-plane
geometry -> a VisionObservation. No bus and no clock of its own: the service and `tiplog vision
run` both call `Pipeline.process`, so live and offline results are the same.

Geometry (camera frame, metres; tiplog.geometry.vision): the labeler's lines give the tangent
plane normals n_L, n_R (n_L x n_R along the shaft toward the tip), P0 = rho_s (n_L + n_R) /
(1 + n_L.n_R); the junction seen in the image lies on the shaft's end rim nearest the camera,
so it is moved onto the axis (junction_on_axis) and reported as the axis point's pixel and ray;
it is dropped when 1 - (d.u)^2 < 0.45 (u = n_L x n_R).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.vision import edges
from services.vision.gate import GateMeasures, GateParams, measures
from services.vision.labeler import (
    JUNCTION_RIM_FRACTION,
    LabelerParams,
    ShaftLabel,
    label_frame,
    label_mask,
    lines_from_blob,
)
from tiplog.geometry import vision as vg
from tiplog.geometry.camera import CameraModel
from tiplog.v1 import vision_pb2

if TYPE_CHECKING:  # torch is imported only where a network runs (`tiplog up` reads the config model)
    from services.vision.network import Segmenter


class PipelineParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    labeler: LabelerParams = Field(default_factory=LabelerParams)
    gate: GateParams = Field(default_factory=GateParams)
    net_threshold: float = Field(0.5, gt=0.0, lt=1.0, description="network mask: probability above this")
    rim_junction: bool = Field(True, description="move the junction from the end rim onto the axis")


@dataclass
class FrameResult:
    """The observation and what it was made from (for the preview, tests and benchmarks)."""

    obs: vision_pb2.VisionObservation
    label: ShaftLabel
    net_label: ShaftLabel | None
    prob: np.ndarray | None
    gate: GateMeasures | None
    timings_ms: dict[str, float] = field(default_factory=dict)


def network_lines(prob: np.ndarray, camera: CameraModel, seg: Segmenter, p: PipelineParams) -> ShaftLabel:
    """Lines and junction of the network's mask, found as the labeler finds them in an image (the
    mask's darkness 1 - p, sampled on the network's grid)."""
    spec = seg.spec
    h, w = prob.shape
    uv = edges.grid_undistorted(camera, float(spec.step), spec.grid_offset, h, w)
    blob = edges.find_blob(prob > p.net_threshold, uv, spec.step, max(4, p.labeler.min_blob_cells // 2))
    if isinstance(blob, str):
        return ShaftLabel(False, blob)
    dark = (1.0 - prob).astype(np.float32)
    # a probability step of 1 spans about one grid cell, 1 / step per full-resolution pixel; a
    # tenth of that is still an edge
    min_step = 0.1 / spec.step
    return lines_from_blob(
        dark, camera, float(spec.step), spec.grid_offset, blob, float(spec.step),
        window_px=1.5 * spec.step, min_step=min_step, keep_fraction=p.labeler.keep_fraction,
        min_points=p.labeler.min_edge_points, junction_min_step=min_step, junction_lines=(0.15, 0.3, 0.45),
    )  # fmt: skip


def _vec(v: vision_pb2.VisionObservation, name: str, x: np.ndarray) -> None:
    m = getattr(v, name)
    m.x, m.y, m.z = (float(c) for c in x)


class Pipeline:
    """Labeler + network + gate + geometry for frames of one camera."""

    def __init__(self, segmenter: Segmenter | None, shaft_radius_m: float, params: PipelineParams | None = None):
        if not shaft_radius_m > 0:
            raise ValueError(f"shaft_radius_m must be positive (got {shaft_radius_m})")
        self.seg = segmenter
        self.rho = float(shaft_radius_m)
        self.p = params or PipelineParams()

    def process(self, frame_rgb: np.ndarray, camera: CameraModel, stamp_ns: int, seq: int = 0) -> FrameResult:
        """One (H, W, 3) uint8 RGB frame of `camera`; the observation carries `stamp_ns` unchanged."""
        t0, c0 = time.perf_counter(), time.thread_time()
        lab = label_frame(frame_rgb, camera, self.p.labeler)
        t1, c1 = time.perf_counter(), time.thread_time()
        prob = net = gm = None
        if self.seg is not None:
            prob = self.seg.probabilities(frame_rgb)
        t2, c2 = time.perf_counter(), time.thread_time()
        obs = vision_pb2.VisionObservation()
        obs.header.stamp_ns = int(stamp_ns)
        obs.header.seq = int(seq)
        obs.header.frame_id = camera.frame_id
        reasons: list[str] = []
        if not lab.ok:
            reasons.append(f"labeler:{lab.reason}")
        if prob is not None:
            net = network_lines(prob, camera, self.seg, self.p)  # type: ignore[arg-type]
            spec = self.seg.spec  # type: ignore[union-attr]
            uv = edges.grid_undistorted(camera, float(spec.step), spec.grid_offset, *prob.shape)
            gm = measures(lab, net, label_mask(lab, uv), prob > self.p.net_threshold)
            obs.mask_iou = gm.mask_iou
            obs.line_angle_deg = _finite(gm.line_angle_deg)
            obs.lateral_px = _finite(gm.lateral_px)
            obs.junction_diff_px = _finite(gm.junction_diff_px)
            if lab.ok:
                if not net.ok:
                    reasons.append(f"network:{net.reason}")
                reasons.extend(gm.reasons(self.p.gate))
        if lab.ok:
            self._geometry(obs, lab, camera)
        obs.accepted = lab.ok and not reasons
        obs.reject_reason = reasons[0] if reasons else ""
        t3, c3 = time.perf_counter(), time.thread_time()
        obs.processing_ms = (t3 - t0) * 1e3
        # wall time, and CPU time of this thread (what the frame costs on a core of its own)
        timings = {
            "labeler_ms": (t1 - t0) * 1e3,
            "network_ms": (t2 - t1) * 1e3,
            "total_ms": (t3 - t0) * 1e3,
            "labeler_cpu_ms": (c1 - c0) * 1e3,
            "network_cpu_ms": (c2 - c1) * 1e3,
            "total_cpu_ms": (c3 - c0) * 1e3,
        }
        return FrameResult(obs, lab, net, prob, gm, timings)

    def _geometry(self, obs: vision_pb2.VisionObservation, lab: ShaftLabel, cam: CameraModel) -> None:
        K = (cam.fx, cam.fy, cam.cx, cam.cy)
        n_l = vg.normal_from_image_line(lab.line_left, *K)
        n_r = vg.normal_from_image_line(lab.line_right, *K)
        p0 = vg.p0_from_normals(n_l, n_r, self.rho)
        _vec(obs, "n_left", n_l)
        _vec(obs, "n_right", n_r)
        _vec(obs, "axis_point_m", p0)
        obs.line_residual_px = lab.residual_px
        if not lab.junction_visible:
            return
        u = vg.axis_direction_from_normals(n_l, n_r)
        ray = cam.pixel_to_ray(lab.junction_px, distorted=False)
        j_axis, _, cond = vg.junction_on_axis(ray, p0, u, self.rho, self.p.rim_junction, JUNCTION_RIM_FRACTION)
        if not (np.isfinite(cond) and cond >= self.p.gate.min_junction_sin2 and j_axis[2] > 0):
            return
        px = cam.project(j_axis, distort=False)
        obs.junction_u_px, obs.junction_v_px = float(px[0]), float(px[1])
        _vec(obs, "junction_ray", j_axis / np.linalg.norm(j_axis))
        obs.junction_visible = True


def _finite(x: float) -> float:
    """Proto fields carry -1 for a measure that could not be taken (a side saw no shaft)."""
    return float(x) if np.isfinite(x) else -1.0
