from __future__ import annotations

import numpy as np
import pytest

from tiplog.geometry.camera import CameraModel


def test_project_and_back_project_round_trip():
    cam = CameraModel.d405_colour()
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.1, 0.1, 500), rng.uniform(-0.06, 0.06, 500), rng.uniform(0.15, 0.4, 500)])
    uv = cam.project(p)
    rays = cam.pixel_to_ray(uv)
    expected = p / np.linalg.norm(p, axis=1, keepdims=True)
    assert np.max(np.abs(rays - expected)) < 1e-9
    # distortion moves off-centre points by pixels, not by nothing
    assert np.max(np.linalg.norm(uv - cam.project(p, distort=False), axis=1)) > 1.0


def test_behind_camera_is_nan_and_calibration_round_trip():
    cam = CameraModel.d405_colour()
    assert np.all(np.isnan(cam.project(np.array([0.0, 0.0, -1.0]))))
    again = CameraModel.from_calibration(cam.to_calibration(123))
    assert again == cam


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="focal"):
        CameraModel(640, 480, -1, 500, 320, 240)
    with pytest.raises(ValueError, match="k1, k2, p1, p2, k3"):
        CameraModel(640, 480, 500, 500, 320, 240, (0.1, 0.2))
