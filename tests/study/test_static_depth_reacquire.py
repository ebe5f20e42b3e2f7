"""The static-trial filter reopens a depth that converged to a wrong value: vision frames that
agree on another depth, refused on innovation five times in a row, are then taken (the bench
case: one translation trial stuck 8.6 mm off along the shaft). Synthetic frames from the
calibration's own geometry, so the planes agree and only the depth is in question."""

from __future__ import annotations

import numpy as np
import pytest

from study.static_filter import E_S, StaticFilter, StaticParams
from tests.services.fusion.sessions import bench_geometry
from tiplog.calibration import Calibration
from tiplog.geometry.vision import closest_axis_point, tangent_plane_normals


@pytest.fixture(scope="module")
def geometry(tmp_path_factory):
    return bench_geometry(tmp_path_factory)


def _frame(calib: Calibration, R: np.ndarray, L_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = calib.R_base_camera.T
    rcm_cam = A @ (calib.rcm_base_m - calib.p_base_camera_m)
    u_cam = A @ R @ E_S
    n_l, n_r = tangent_plane_normals(closest_axis_point(rcm_cam, u_cam), u_cam, calib.shaft_radius_m)
    axis_s = L_m - calib.junction_proximal_m + calib.vision_tip_offset_m  # the junction along the axis
    return n_l, n_r, rcm_cam + axis_s * u_cam


@pytest.mark.parametrize("frames, reopened", [(0, False), (5, True)])
def test_a_stuck_depth_is_reopened_by_agreeing_frames(geometry, frames, reopened):
    calib, R = geometry
    f = StaticFilter(calib, StaticParams(depth_reacquire_frames=frames))
    L_true = 0.130
    s = f.new_state(0, R, L_true + 0.010)
    s.P[6, 6] = (0.3e-3) ** 2  # confidently wrong, as after the ToF's pose-locked error
    for _ in range(12):
        f.update_vision(s, *_frame(calib, R, L_true))
    if reopened:
        assert abs(s.L - L_true) < 1e-3
        assert s.counts.get("reacquire:depth", 0) >= 1
    else:
        assert abs(s.L - L_true) > 9e-3
        assert s.counts["rejected:vision_depth:innovation"] == 12
