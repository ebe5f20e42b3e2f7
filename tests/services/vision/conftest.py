"""Frames for the vision tests: the bench's renderer at a few fixed poses like those of the
demo and teleoperated sessions (the tip 8-9 cm in front of the camera, the shaft entering from
the left), with the renderer's exact geometry as truth. Rendered once per test session."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.render.renderer import RenderParams, render_frame
from services.bench.scenario import load_scenario

SHAFT_RADIUS_M = 0.00259
JUNCTION_M = 0.004
POSES = [  # (tip in the camera frame [m], shaft axis toward the tip, roll about it [rad])
    ((0.0014, 0.0107, 0.0815), (0.9697, 0.0760, 0.2323), 0.3),
    ((-0.0100, -0.0080, 0.0900), (0.9500, -0.1200, 0.2800), 1.7),
    ((0.0120, 0.0040, 0.0780), (0.9600, 0.1500, 0.2200), -0.9),
]


def pose_matrix(tip, axis, roll) -> np.ndarray:
    """T_camera_tool (4x4): tool z along `axis`, origin at `tip`."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    T[:3, 3] = tip
    return T


@pytest.fixture(scope="session")
def camera():
    return load_scenario("demo").camera.model()


@pytest.fixture(scope="session")
def render_params():
    return RenderParams(
        shaft_radius_m=SHAFT_RADIUS_M,
        junction_from_tip_mm=JUNCTION_M * 1e3,
        smoke_probability=0.0,
        occlusion_probability=0.0,
    )


@pytest.fixture(scope="session")
def rendered(camera, render_params):
    """[(frame (720, 1280, 3) uint8, truth dict, T_camera_tool)] at the fixed poses, seeded."""
    rng = np.random.default_rng(7)
    out = []
    for tip, axis, roll in POSES:
        T = pose_matrix(tip, axis, roll)
        truth: dict = {}
        img = render_frame(camera, T, render_params, rng, truth_out=truth)
        out.append((img, truth, T))
    return out


@pytest.fixture(scope="session")
def blank_frame(camera, render_params):
    """The phantom alone: the instrument far outside the view."""
    T = pose_matrix((0.3, 0.3, 0.1), (0.0, 0.0, 1.0), 0.0)
    return render_frame(camera, T, render_params, np.random.default_rng(8))


@pytest.fixture(scope="session")
def recording(tmp_path_factory):
    """A 1 s pixel-tier demo session (15 frames, device streams, calibration metadata)."""
    from services.bench.session import generate

    path = tmp_path_factory.mktemp("vision") / "pixel.mcap"
    generate(load_scenario("demo"), path, seed=1001, tier="pixel", duration_s=1.0)
    return path
