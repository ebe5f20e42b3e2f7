"""One frame through labeler, network, gate and geometry, with the shipped checkpoint."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from services.vision import DEFAULT_WEIGHTS
from services.vision.gate import GateParams
from services.vision.network import load_checkpoint
from services.vision.pipeline import Pipeline, PipelineParams
from services.vision.preview import preview_message
from tests.services.vision.conftest import JUNCTION_M, SHAFT_RADIUS_M
from tiplog.geometry import vision as vg


@pytest.fixture(scope="module")
def segmenter():
    import torch

    torch.set_num_threads(1)
    return load_checkpoint(DEFAULT_WEIGHTS, "cpu")[0]


def _v(m) -> np.ndarray:
    return np.array([m.x, m.y, m.z])


def test_rendered_frames_are_accepted_with_the_true_geometry(rendered, camera, segmenter):
    pipe = Pipeline(segmenter, SHAFT_RADIUS_M)
    for k, (img, truth, T) in enumerate(rendered):
        res = pipe.process(img, camera, stamp_ns=123_456_789_000 + k, seq=k)
        o = res.obs
        assert o.header.stamp_ns == 123_456_789_000 + k and o.header.seq == k  # capture stamp unchanged
        assert o.accepted, (o.reject_reason, res.gate)
        assert o.mask_iou >= 0.75 and o.line_angle_deg < 0.5 and o.lateral_px < 1.5 and 0 <= o.junction_diff_px < 4
        u = T[:3, 2]
        for n, n_true in ((_v(o.n_left), truth["n_left_cam"]), (_v(o.n_right), truth["n_right_cam"])):
            assert np.degrees(np.arccos(min(1.0, n @ n_true))) < 0.05
        J = T[:3, 3] - JUNCTION_M * u
        p0 = vg.closest_axis_point(J, u)
        assert np.linalg.norm(_v(o.axis_point_m) - p0) < 2e-3  # P0 from the normals: ill-conditioned in depth
        assert o.junction_visible
        _, on_axis, _ = vg.ray_axis_intersection(_v(o.junction_ray), p0, u)
        assert abs((on_axis - J) @ u) < 0.3e-3
        assert np.hypot(o.junction_u_px - truth["junction_px"][0], o.junction_v_px - truth["junction_px"][1]) < 1.5
        assert o.processing_ms > 0 and set(res.timings_ms) == {
            f"{stage}{kind}" for stage in ("labeler", "network", "total") for kind in ("_ms", "_cpu_ms")
        }


def test_each_gate_threshold_rejects_with_its_reason(rendered, camera, segmenter):
    img = rendered[0][0]
    cases = {
        "gate:mask_iou": GateParams(min_mask_iou=0.9999),
        "gate:line_angle": GateParams(max_line_angle_deg=1e-9),
        "gate:lateral": GateParams(max_lateral_px=1e-9),
        "gate:junction": GateParams(max_junction_px=1e-9),
    }
    for reason, gate in cases.items():
        o = Pipeline(segmenter, SHAFT_RADIUS_M, PipelineParams(gate=gate)).process(img, camera, 1).obs
        assert not o.accepted and o.reject_reason == reason
        assert np.linalg.norm(_v(o.n_left)) == pytest.approx(1.0)  # the geometry is still reported


def test_ill_conditioned_junction_is_dropped(rendered, camera, segmenter):
    o = (
        Pipeline(segmenter, SHAFT_RADIUS_M, PipelineParams(gate=GateParams(min_junction_sin2=1.0)))
        .process(rendered[0][0], camera, 1)
        .obs
    )
    assert o.accepted and not o.junction_visible


def test_frame_without_shaft_is_rejected_with_the_labelers_reason(blank_frame, camera, segmenter):
    o = Pipeline(segmenter, SHAFT_RADIUS_M).process(blank_frame, camera, 5).obs
    assert not o.accepted and o.reject_reason == "labeler:no_shaft" and o.header.stamp_ns == 5


def test_preview_is_a_small_jpeg_of_the_frame(rendered, camera, segmenter):
    img = rendered[1][0]
    res = Pipeline(segmenter, SHAFT_RADIUS_M).process(img, camera, 77)
    m = preview_message(img, res, camera, width_px=320)
    assert m.format == "jpeg" and m.timestamp.ToNanoseconds() == 77
    pic = cv2.imdecode(np.frombuffer(m.data, np.uint8), cv2.IMREAD_COLOR)
    assert pic.shape == (180, 320, 3)
    assert len(m.data) < 40_000
