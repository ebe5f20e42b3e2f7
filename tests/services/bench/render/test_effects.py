"""Pixel tier in motion: exposure blur, the lens residual, shaft tilt, episodes (second instrument,
smoke, glare) and the per-profile RenderParams values."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from services.bench.render.effects import (
    RENDER_PROFILE_OVERRIDES,
    Episode,
    RenderSession,
    draw_episodes,
    lens_as_built,
    shaft_tilt,
)
from services.bench.render.renderer import RenderParams, render_frame
from tests.services.bench.render.test_renderer import CLEAN, D405, POSES, gray, look_down_pose

PAPER = RenderParams(**RENDER_PROFILE_OVERRIDES["paper"])


def _session(params: RenderParams, seed: int = 0, duration_s: float = 60.0) -> RenderSession:
    return RenderSession.create(
        D405, params, duration_s, params.junction_from_tip_mm * 1e-3, np.random.default_rng(seed)
    )


def _sweep(T: np.ndarray, shift_cam_m: np.ndarray, m: int = 9) -> np.ndarray:
    """m poses of T translated evenly by -shift/2 .. +shift/2 (camera frame)."""
    out = np.repeat(T[None], m, axis=0)
    out[:, :3, 3] += np.linspace(-0.5, 0.5, m)[:, None] * shift_cam_m
    return out


def test_profiles_are_render_params_and_clean_is_the_default():
    assert RENDER_PROFILE_OVERRIDES["clean"] == {}
    for name, ov in RENDER_PROFILE_OVERRIDES.items():
        RenderParams(**ov)  # every value valid
        assert set(ov) <= set(RenderParams.model_fields), name
    paper, harsh = RENDER_PROFILE_OVERRIDES["paper"], RENDER_PROFILE_OVERRIDES["harsh"]
    assert set(paper) == set(harsh)
    for k, v in paper.items():  # harsh is at least paper in every source
        hv = harsh[k]
        assert (max(hv) >= max(v)) if isinstance(v, tuple) else hv >= 1.5 * v, k


def test_bad_duration_range_refused():
    with pytest.raises(ValidationError, match="smoke_duration_s must run from min to max"):
        RenderParams(smoke_duration_s=(5.0, 2.0))
    with pytest.raises(ValidationError):
        RenderParams(exposure_ms=-1.0)


def test_default_session_draws_the_same_frame_as_none():
    p = RenderParams()
    s = _session(p)
    assert s.lens == D405 and np.array_equal(s.T_tool_shaft, np.eye(4)) and s.episodes == ()
    for T in POSES:
        a = render_frame(D405, T, p, np.random.default_rng(4))
        b = render_frame(D405, T, p, np.random.default_rng(4), t_s=3.0, session=s)
        assert np.array_equal(a, b)


def test_exposure_at_rest_is_one_render_and_in_motion_blurs_the_edges():
    p = RenderParams(**CLEAN, exposure_ms=16.0)
    T = POSES[0]
    still, rest, moving = {}, {}, {}
    img0 = render_frame(D405, T, p, np.random.default_rng(0), still)
    img_rest = render_frame(D405, np.repeat(T[None], 9, axis=0), p, np.random.default_rng(0), rest)
    assert rest["subframes"] == 1 and np.array_equal(img0, img_rest)
    # 8 px of image motion across the shaft during the exposure
    n = np.array([*still["line_left"][:2], 0.0])
    shift = n * 8.0 * T[2, 3] / D405.fx
    img_mov = render_frame(D405, _sweep(T, shift), p, np.random.default_rng(0), moving)
    assert moving["subframes"] == 9
    assert np.allclose(moving["p_tip_cam_m"], still["p_tip_cam_m"])  # truth at the middle pose
    g0, g1 = gray(img0), gray(img_mov)
    # the edge's steepest step is spread over the motion: the largest gradient across it falls
    rows = np.flatnonzero(still["mask"].any(axis=1))[20:-20]
    steep0 = np.abs(np.diff(g0[rows], axis=1)).max(axis=1)
    steep1 = np.abs(np.diff(g1[rows], axis=1)).max(axis=1)
    assert np.median(steep1) < 0.6 * np.median(steep0)


def test_exposure_needs_an_odd_number_of_poses():
    with pytest.raises(ValueError, match="M odd"):
        render_frame(D405, np.repeat(POSES[0][None], 4, axis=0), RenderParams(), np.random.default_rng(0))


def test_lens_residual_moves_the_image_and_is_off_by_default():
    assert lens_as_built(D405, RenderParams(), np.random.default_rng(1)) == D405
    lens = lens_as_built(D405, RenderParams(lens_error_sd_frac=0.002, lens_k1_error_sd=0.004), np.random.default_rng(1))
    assert lens != D405
    assert abs(lens.cx - D405.cx) < 0.01 * D405.fx and abs(lens.fx / D405.fx - 1) < 0.01
    p = RenderParams(**CLEAN, lens_error_sd_frac=0.002)
    s = _session(p, seed=1)
    t_stated, t_lens = {}, {}
    render_frame(D405, POSES[1], RenderParams(**CLEAN), np.random.default_rng(0), t_stated)
    render_frame(D405, POSES[1], p, np.random.default_rng(0), t_lens, session=s)
    shift = np.linalg.norm(t_lens["junction_px_distorted"] - t_stated["junction_px_distorted"])
    assert 0.05 < shift < 10.0


def test_shaft_tilt_pivots_about_the_junction():
    j = 0.012
    T = shaft_tilt(RenderParams(shaft_tilt_sd_deg=0.5), j, np.random.default_rng(3))
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3))
    assert np.allclose(T @ [0.0, 0.0, -j, 1.0], [0.0, 0.0, -j, 1.0])
    ang = np.degrees(np.arccos(np.clip(T[2, 2], -1, 1)))
    assert 0.0 < ang < 2.5
    assert np.array_equal(shaft_tilt(RenderParams(), j, np.random.default_rng(3)), np.eye(4))


def test_episodes_follow_their_rate_and_duration():
    p = RenderParams(occluder_rate_per_min=2.0, occluder_duration_s=(1.0, 4.0), glare_rate_per_min=0.0)
    eps = draw_episodes(p, 1800.0, np.random.default_rng(5))
    occ = [e for e in eps if e.kind == "occluder"]
    assert not any(e.kind == "glare" for e in eps)
    # 30 min at 2/min, each 2.5 s on average: about 59 episodes; Poisson SD about 8
    assert 35 < len(occ) < 85
    d = np.array([e.t1_s - e.t0_s for e in occ])
    assert d.min() >= 1.0 and d.max() <= 4.0
    assert all(a.t1_s <= b.t0_s for a, b in zip(occ[:-1], occ[1:], strict=True))  # one at a time per kind
    assert draw_episodes(p, 1800.0, np.random.default_rng(5)) == eps
    # one kind's rate leaves the other kinds' episodes as they were
    more = draw_episodes(p.model_copy(update={"glare_rate_per_min": 3.0}), 1800.0, np.random.default_rng(5))
    assert [e for e in more if e.kind == "occluder"] == occ


@pytest.mark.parametrize("kind", ["occluder", "smoke", "glare"])
def test_episode_shows_while_under_way_only(kind):
    p = RenderParams(**CLEAN)
    s = RenderSession(D405, np.eye(4), (Episode(kind, 10.0, 14.0, 12345),))
    T = POSES[0]
    before, during = {}, {}
    img_b = render_frame(D405, T, p, np.random.default_rng(0), before, t_s=9.9, session=s)
    img_d = render_frame(D405, T, p, np.random.default_rng(0), during, t_s=12.0, session=s)
    assert before["occlusion"] == "none" and not before["smoke"] and not before["glare"]
    assert np.array_equal(img_b, render_frame(D405, T, p, np.random.default_rng(0)))
    diff = np.abs(gray(img_d) - gray(img_b))
    if kind == "occluder":
        assert during["occlusion"] == "instrument" and (during["occluder_mask"] & before["mask"]).any()
    elif kind == "smoke":
        assert during["smoke"] and np.mean(diff > 2) > 0.2  # a haze over much of the view
    else:
        assert during["glare"] and (img_d.min(axis=2) == 255).sum() > (img_b.min(axis=2) == 255).sum()
        assert 0 < np.mean(diff > 2) < 0.05  # local spots


def test_occluder_moves_smoothly_over_its_episode():
    p = RenderParams(**CLEAN)
    s = RenderSession(D405, np.eye(4), (Episode("occluder", 0.0, 4.0, 7),))
    T = look_down_pose([0.0, 0.0, 0.25])
    masks = []
    for t in (1.9, 2.0, 2.1):
        tr: dict = {}
        render_frame(D405, T, p, np.random.default_rng(0), tr, t_s=t, session=s)
        masks.append(tr["occluder_mask"])
    a, b, c = (m.sum() for m in masks)
    assert a > 0 and b > 0 and c > 0
    iou = (masks[0] & masks[1]).sum() / (masks[0] | masks[1]).sum()
    assert iou > 0.8  # 0.1 s apart: the same instrument, moved a little


def test_every_profile_renders_with_its_own_render_section():
    from services.bench.scenario import load_scenario

    for name, ov in RENDER_PROFILE_OVERRIDES.items():
        params = load_scenario("demo", [f"profile={name}"]).render
        assert params == RenderParams(**ov), name
    assert load_scenario("demo").render == RenderParams(**RENDER_PROFILE_OVERRIDES["paper"])  # the default


def test_simulated_pixel_session_renders_over_the_exposure_deterministically():
    from services.bench.scenario import load_scenario
    from services.bench.simulation import simulate_session

    ov = {f"render.{k}": v for k, v in RENDER_PROFILE_OVERRIDES["paper"].items()}
    sc = load_scenario("static", ov)
    a = simulate_session(sc, 1, "pixel", 0.4)
    b = simulate_session(sc, 1, "pixel", 0.4)
    img_a, img_b = a.render_frame(1), b.render_frame(1)
    assert np.array_equal(img_a, img_b)
    s = a._render_session
    assert s.lens != sc.camera.model() and not np.array_equal(s.T_tool_shaft, np.eye(4))
    # the clean profile draws what the renderer draws at the frame's instant, with no session effects
    clean = load_scenario("static", ["profile=clean"])
    c = simulate_session(clean, 1, "pixel", 0.4)
    ref = simulate_session(clean, 1, "pixel", 0.4)  # its generator where c's starts
    img_c = c.render_frame(0)
    direct = render_frame(clean.camera.model(), ref.frame_pose_cam(0), c._render_params, ref._render_rng)
    assert np.array_equal(img_c, direct)
