"""Pixel renderer: exact silhouettes, truth masks, determinism, parameter validation, chance events."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from services.bench.render.renderer import RenderParams, get_scene, render_frame
from tiplog.geometry.camera import CameraModel

PINHOLE = CameraModel(1280, 720, 652.0, 651.0, 641.3, 358.7)
D405 = CameraModel.d405_colour()
CLEAN = dict(sensor_noise=False, smoke_probability=0.0, occlusion_probability=0.0)


def look_down_pose(p_tip_cam_m, from_vertical_deg=28.6, azimuth_deg=200.0) -> np.ndarray:
    """T_camera_tool for a camera looking straight down (+z) at a shaft tilted from the vertical."""
    th, az = np.radians(from_vertical_deg), np.radians(azimuth_deg)
    z = np.array([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)])
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = p_tip_cam_m
    return T


POSES = [
    look_down_pose([-0.02, 0.01, 0.27]),
    look_down_pose([0.01, -0.03, 0.22], 35.0, 100.0),
    look_down_pose([0.03, 0.02, 0.30], 20.0, 320.0),
]


def gray(img: np.ndarray) -> np.ndarray:
    return img.astype(np.float64).mean(axis=2)


def edge_errors_px(g: np.ndarray, line: np.ndarray, truth: dict, exclude_px: float) -> np.ndarray:
    """Gradient-maximum edge positions across `line`, one per image row (or column), each as its
    signed perpendicular distance [px] from the line; skips the jaws' neighbourhood and the borders."""
    a, b, c = line
    h, w = g.shape
    along_rows = abs(a) >= abs(b)  # line more vertical than horizontal: scan rows
    out = []
    for k in range(8, (h if along_rows else w) - 8):
        pos = -(b * k + c) / a if along_rows else -(a * k + c) / b
        if not 8 <= pos <= (w if along_rows else h) - 9:
            continue
        uv = np.array([pos, k]) if along_rows else np.array([k, pos])
        if np.hypot(*(uv - truth["junction_px"])) < exclude_px or np.hypot(*(uv - truth["tip_px"])) < exclude_px:
            continue
        if not (truth["mask"].any(axis=1 if along_rows else 0)[k]):
            continue
        i0 = int(round(pos))
        idx = np.arange(i0 - 4, i0 + 5)
        prof = g[k, idx] if along_rows else g[idx, k]
        grad = np.abs(prof[2:] - prof[:-2])
        m = int(np.argmax(grad[1:-1])) + 1
        y0, y1, y2 = grad[m - 1], grad[m], grad[m + 1]
        den = y0 - 2 * y1 + y2
        sub = 0.5 * (y0 - y2) / den if den != 0 else 0.0
        p = idx[m + 1] + sub
        q = (p, k) if along_rows else (k, p)
        out.append(a * q[0] + b * q[1] + c)
    return np.array(out)


@pytest.mark.parametrize("pose", range(len(POSES)))
@pytest.mark.parametrize("blur", [0.0, 0.8])
def test_silhouette_edges_on_analytic_tangent_lines(pose, blur):
    # a plain floor isolates the renderer's geometry from texture crossing the edge
    truth: dict = {}
    params = RenderParams(blur_sigma_px=blur, texture_strength=0.0, **CLEAN)
    g = gray(render_frame(PINHOLE, POSES[pose], params, np.random.default_rng(0), truth))
    for name in ("line_left", "line_right"):
        err = edge_errors_px(g, truth[name], truth, exclude_px=40.0)
        assert len(err) > 50, name
        assert np.max(np.abs(err)) < 0.1, (name, np.max(np.abs(err)))
        assert abs(np.mean(err)) < 0.03, (name, np.mean(err))


@pytest.mark.parametrize("pose", range(len(POSES)))
def test_silhouette_edges_over_tissue_texture(pose):
    # texture beside the edge moves single gradient maxima a little, never the line
    truth: dict = {}
    g = gray(render_frame(PINHOLE, POSES[pose], RenderParams(**CLEAN), np.random.default_rng(0), truth))
    for name in ("line_left", "line_right"):
        err = edge_errors_px(g, truth[name], truth, exclude_px=40.0)
        assert np.percentile(np.abs(err), 99) < 0.2, name
        assert np.max(np.abs(err)) < 0.35, name
        assert abs(np.mean(err)) < 0.05, name


def test_edges_with_lens_distortion_in_undistorted_coordinates():
    cv2 = pytest.importorskip("cv2")
    truth: dict = {}
    params = RenderParams(blur_sigma_px=0.8, texture_strength=0.0, **CLEAN)
    img = render_frame(D405, POSES[0], params, np.random.default_rng(0), truth)
    # resample the frame onto undistorted pixel coordinates, as the labeler does
    vv, uu = np.mgrid[0:720, 0:1280].astype(np.float64)
    xy = np.stack([(uu - D405.cx) / D405.fx, (vv - D405.cy) / D405.fy], -1)
    xyd = D405.distort_normalized(xy)
    mx = (xyd[..., 0] * D405.fx + D405.cx).astype(np.float32)
    my = (xyd[..., 1] * D405.fy + D405.cy).astype(np.float32)
    und = cv2.remap(gray(img).astype(np.float32), mx, my, cv2.INTER_CUBIC)
    for name in ("line_left", "line_right"):
        err = edge_errors_px(und.astype(np.float64), truth[name], truth, exclude_px=40.0)
        assert len(err) > 50
        assert np.max(np.abs(err)) < 0.15, (name, np.max(np.abs(err)))
        assert abs(np.mean(err)) < 0.03, (name, np.mean(err))


def test_tangent_planes_match_the_paper_geometry():
    truth: dict = {}
    render_frame(PINHOLE, POSES[1], RenderParams(**CLEAN), np.random.default_rng(0), truth)
    n_l, n_r, u = truth["n_left_cam"], truth["n_right_cam"], truth["axis_cam"]
    rho = RenderParams().shaft_radius_m
    assert abs(n_l @ u) < 1e-12 and abs(n_r @ u) < 1e-12
    # closest axis point to the camera centre from the sum of the normals (paper, eq. P0)
    p0 = rho * (n_l + n_r) / (1 + n_l @ n_r)
    tip = truth["p_tip_cam_m"]
    closest = tip - (tip @ u) * u
    np.testing.assert_allclose(p0, closest, atol=1e-9)
    # the junction pixel lies on the projected axis, between the two lines
    j = np.append(truth["junction_px"], 1.0)
    dl, dr = truth["line_left"] @ j, truth["line_right"] @ j
    assert dl > 0 and dr > 0 and abs(dl - dr) < 0.5


@pytest.mark.parametrize("camera", [PINHOLE, D405], ids=["pinhole", "d405"])
def test_mask_matches_geometry_and_image(camera):
    truth: dict = {}
    params = RenderParams(blur_sigma_px=0.0, **CLEAN)
    img = render_frame(camera, POSES[0], params, np.random.default_rng(0), truth)
    mask, jaws = truth["mask"], truth["jaws_mask"]
    assert mask.shape == (720, 1280) and mask.dtype == bool
    assert mask.sum() > 5000 and jaws.sum() > 20 and not (mask & jaws).any()
    # every mask pixel's centre (in undistorted coordinates) is inside both tangent lines
    iy, ix = np.nonzero(mask | jaws)
    uv = camera.undistort_pixels(np.stack([ix, iy], -1).astype(float)) if camera is D405 else np.stack([ix, iy], -1)
    for name in ("line_left", "line_right"):
        a, b, c = truth[name]
        assert np.all(a * uv[:, 0] + b * uv[:, 1] + c >= -1e-9)
    # and the mask is what the frame shows: where it departs from the bare floor
    floor = get_scene(camera, params).floor_dn
    drawn = np.abs(img - floor).max(axis=2) > 8
    iou = (drawn & (mask | jaws)).sum() / (drawn | mask | jaws).sum()
    assert iou > 0.95, iou
    # the jaws touch the shaft near the junction pixel
    jd = camera.project(truth["p_junction_cam_m"])
    near = np.hypot(ix - jd[0], iy - jd[1]) < 4
    assert near.any()


def test_frame_format_and_seeded_determinism():
    params = RenderParams(smoke_probability=0.5, occlusion_probability=0.5)
    a = render_frame(D405, POSES[2], params, np.random.default_rng(7))
    b = render_frame(D405, POSES[2], params, np.random.default_rng(7))
    c = render_frame(D405, POSES[2], params, np.random.default_rng(8))
    assert a.shape == (720, 1280, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_noise_level_follows_signal():
    params = RenderParams(smoke_probability=0.0, occlusion_probability=0.0)
    f = [render_frame(PINHOLE, POSES[0], params, np.random.default_rng(s)).astype(float) for s in range(2)]
    clean = render_frame(PINHOLE, POSES[0], RenderParams(**CLEAN), np.random.default_rng(0)).astype(float)
    diff = (f[0] - f[1]) / np.sqrt(2)
    bright = clean > 120
    expected = np.sqrt(params.read_noise_dn**2 + clean[bright].mean() / params.electrons_per_dn)
    assert 0.8 * expected < diff[bright].std() < 1.2 * expected
    assert abs((f[0] - clean).mean()) < 0.2  # unbiased on average


@pytest.mark.parametrize(
    "bad",
    [
        dict(shaft_radius_m=-0.001),
        dict(jaw_radius_m=0.003),
        dict(smoke_probability=1.5),
        dict(blur_sigma_px=-1.0),
        dict(floor_normal_cam=(0.0, 0.0, 1.0)),
        dict(floor_colour=(1.2, 0.5, 0.5)),
        dict(exposure=0.0),
        dict(no_such_field=1),
    ],
)
def test_bad_params_are_rejected(bad):
    with pytest.raises(ValidationError):
        RenderParams(**bad)


def test_bad_poses_are_rejected():
    with pytest.raises(ValueError, match="4x4"):
        render_frame(PINHOLE, np.eye(3), RenderParams(), np.random.default_rng(0))
    T = np.eye(4)
    T[:3, :3] *= 1.1
    T[:3, 3] = [0.0, 0.0, 0.2]
    with pytest.raises(ValueError, match="orthonormal"):
        render_frame(PINHOLE, T, RenderParams(), np.random.default_rng(0))
    T = np.eye(4)
    T[:3, 3] = [0.001, 0.0, 0.1]  # shaft axis through (nearly) the camera centre
    with pytest.raises(ValueError, match="inside"):
        render_frame(PINHOLE, T, RenderParams(), np.random.default_rng(0))


@pytest.mark.parametrize("field", ["smoke_probability", "occlusion_probability"])
def test_chance_events_change_the_frame(field):
    base = dict(CLEAN)
    off = render_frame(PINHOLE, POSES[0], RenderParams(**base), np.random.default_rng(3))
    truth: dict = {}
    base[field] = 1.0
    on = render_frame(PINHOLE, POSES[0], RenderParams(**base), np.random.default_rng(3), truth)
    changed = np.abs(on.astype(int) - off.astype(int)).max(axis=2) > 3
    assert changed.sum() > 500
    if field == "smoke_probability":
        assert truth["smoke"] and truth["occlusion"] == "none"
    else:
        assert truth["occlusion"] in ("blob", "instrument") and not truth["smoke"]
        assert truth["occluder_mask"].sum() > 100
        assert changed[truth["occluder_mask"]].mean() > 0.3


def test_every_occlusion_kind_occurs():
    params = RenderParams(occlusion_probability=1.0, smoke_probability=0.0, sensor_noise=False)
    kinds = set()
    for seed in range(12):
        truth: dict = {}
        render_frame(PINHOLE, POSES[1], params, np.random.default_rng(seed), truth)
        kinds.add(truth["occlusion"])
        assert truth["occluder_mask"].any()
    assert kinds == {"blob", "instrument"}


@pytest.mark.parametrize("camera", [PINHOLE, D405], ids=["pinhole", "d405"])
def test_truth_masks_equal_a_whole_frame_cast(camera):
    # the renderer casts only pixels near the instrument; casting every pixel must agree
    from services.bench.render.geometry import InstrumentGeometry
    from services.bench.render.instrument import instrument_masks

    rng = np.random.default_rng(11)
    params = RenderParams(**CLEAN)
    for _ in range(4):
        T = look_down_pose([rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03), rng.uniform(0.2, 0.3)],
                           rng.uniform(18.6, 38.6), rng.uniform(0, 360))  # fmt: skip
        truth: dict = {}
        render_frame(camera, T, params, np.random.default_rng(0), truth)
        geom = InstrumentGeometry.from_pose(T, params.shaft_radius_m, params.jaw_radius_m,
                                            params.junction_from_tip_mm * 1e-3, params.shaft_length_m)  # fmt: skip
        shaft, jaws = instrument_masks(get_scene(camera, params), geom, truth["line_left"], truth["line_right"])
        assert np.array_equal(shaft, truth["mask"]) and np.array_equal(jaws, truth["jaws_mask"])


def test_left_and_right_as_seen_towards_the_tip():
    # camera looking down, the shaft leaning so that its tip points up the image: left is smaller u
    truth: dict = {}
    render_frame(PINHOLE, look_down_pose([0.0, 0.02, 0.25], 28.6, 270.0), RenderParams(**CLEAN),
                 np.random.default_rng(0), truth)  # fmt: skip
    v = truth["junction_px"][1] + 60.0
    u_left = -(truth["line_left"][1] * v + truth["line_left"][2]) / truth["line_left"][0]
    u_right = -(truth["line_right"][1] * v + truth["line_right"][2]) / truth["line_right"][0]
    assert truth["tip_px"][1] < truth["junction_px"][1]
    assert u_left < u_right


def test_jaws_lie_between_junction_and_tip():
    truth: dict = {}
    render_frame(D405, POSES[1], RenderParams(**CLEAN), np.random.default_rng(0), truth)
    iy, ix = np.nonzero(truth["jaws_mask"])
    j, t = truth["junction_px_distorted"], truth["tip_px_distorted"]
    along = ((np.stack([ix, iy], -1) - j) @ (t - j)) / ((t - j) @ (t - j))
    assert along.min() > -0.3 and along.max() < 1.2 and 0.2 < along.mean() < 0.8


def test_depth_dependent_defocus_blurs_but_keeps_edges_on_the_lines():
    truth: dict = {}
    base = dict(blur_sigma_px=0.0, texture_strength=0.0, focus_distance_m=0.6, **CLEAN)
    sharp = render_frame(PINHOLE, POSES[0], RenderParams(**base), np.random.default_rng(0))
    # about 0.3 px at the tip, 1.2 px where the shaft leaves the frame nearest the camera
    params = RenderParams(defocus_px_per_dioptre=0.15, **base)
    soft = render_frame(PINHOLE, POSES[0], params, np.random.default_rng(0), truth)
    assert (np.abs(soft.astype(int) - sharp.astype(int)).max(axis=2) > 5).sum() > 500
    g = gray(soft)
    for name in ("line_left", "line_right"):
        err = edge_errors_px(g, truth[name], truth, exclude_px=40.0)
        # the wider edge mixes in the shading just inside the silhouette: a little looser than sharp
        assert len(err) > 50
        assert np.max(np.abs(err)) < 0.25, (name, np.max(np.abs(err)))
        assert abs(np.mean(err)) < 0.06, (name, np.mean(err))
