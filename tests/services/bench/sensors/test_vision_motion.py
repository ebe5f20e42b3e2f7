"""The measurement tier's vision in motion (paper profile) against the true geometry."""

from __future__ import annotations

import numpy as np

from services.bench.scenario import load_scenario
from services.bench.sensors import device as sensors
from services.bench.sensors import vision_motion as vm
from services.bench.sensors.calibration import true_constants
from services.bench.sensors.vision_model import simulate_vision
from tests.services.bench.synthetic_truth import pivot

NO_BURSTS = {"vision.dropout_rate_per_min": 0.0}


def _run(overrides, duration_s=30.0, angle=None, seed=0, axis=(0.3, 1.0, 0.0)):
    sc = load_scenario("teleop", overrides)
    const = true_constants(sc)
    gt = pivot(sc.motion.R_neutral(), const.rcm_base_m, 0.14, duration_s, np.array(axis), angle)
    kin = sensors.kinematics(gt, const)
    return sc, const, simulate_vision(kin, sc, const, np.random.default_rng(seed))


def _swing(amp_rad, hz):
    return lambda t: amp_rad * np.sin(2 * np.pi * hz * t)


def test_global_shutter_blur_is_the_image_motion_over_the_exposure():
    sc, _, vf = _run(NO_BURSTS, angle=_swing(0.08, 0.5))
    ex = vf.extra
    blur = np.hypot(ex["blur_axial_px"], ex["blur_across_px"])
    per_s = ex["image_speed_px"] * sc.camera.fps  # px/s over one frame period
    moving = per_s > 30
    ratio = blur[moving] / (per_s[moving] * sc.vision.exposure_ms * 1e-3)
    assert np.median(ratio) == np.clip(np.median(ratio), 0.9, 1.1)  # one instant per frame: no row skew
    _, _, longer = _run({**NO_BURSTS, "vision.exposure_ms": 40.0}, angle=_swing(0.08, 0.5))
    assert np.median(np.abs(longer.extra["blur_axial_px"])) > 1.8 * np.median(np.abs(ex["blur_axial_px"]))


def test_junction_error_grows_with_speed_and_the_gate_prefers_good_frames():
    _, _, slow = _run(NO_BURSTS, angle=_swing(0.03, 0.1), duration_s=60.0)
    _, _, fast = _run(NO_BURSTS, angle=_swing(0.12, 0.6), duration_s=60.0)

    def rms(vf, m):
        return float(np.sqrt(np.mean(vf.extra["junction_depth_err_m"][m] ** 2)))

    every = np.ones(len(fast), bool)
    assert rms(fast, every) > 1.3 * rms(slow, np.ones(len(slow), bool))
    assert fast.accepted.mean() < slow.accepted.mean()
    # quality-following gate: the frames it rejects are worse than those it accepts, and it
    # still passes some bad ones
    err = np.abs(fast.extra["junction_depth_err_m"])
    bad = err > np.percentile(err, 80)
    assert rms(fast, ~fast.accepted) > rms(fast, fast.accepted)
    assert 0.05 < fast.accepted[bad].mean() < fast.accepted[~bad].mean()


def test_gate_weight_zero_is_the_independent_draw():
    z = np.array([0.0, 3.0, 10.0])
    n = np.array([-1.0, 0.5, 2.0])
    np.testing.assert_array_equal(vm.gate_measure(z, n, 0.0), np.abs(n))
    np.testing.assert_allclose(vm.gate_measure(z, n, 1.0), np.hypot(z, n))
    np.testing.assert_array_equal(vm.gate_measure(np.zeros(3), n, 1.0), np.abs(n))  # at rest: the draw


def test_correlated_dropouts_blank_runs_of_frames():
    sc, _, vf = _run({"vision.dropout_rate_per_min": 6.0, "vision.dropout_junction_only_frac": 0.0}, duration_s=120.0)
    blank = vf.extra["dropout_frame"]
    assert blank.any() and not vf.accepted[blank].any()
    assert all(r == "dropout" for r, b in zip(vf.reject_reason, blank, strict=True) if b)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], blank.astype(int), [0]])))
    runs_s = (edges[1::2] - edges[::2]) / sc.camera.fps
    lo, hi = sc.vision.dropout_s
    assert runs_s.max() <= hi + 2 / sc.camera.fps
    assert np.median(runs_s) >= lo  # bursts, not single frames


def test_range_growth_outside_the_validated_range():
    v = load_scenario("teleop").vision
    g = vm.range_growth(v, np.array([140.0, 150.0, 160.0, 140.0]), np.array([0.0, 5.0, 0.0, 20.0]))
    assert g[0] == g[1] == 1.0
    assert g[2] == 1.0 + v.range_growth_per_10mm and g[3] == 1.0 + v.range_growth_per_10deg


def test_camera_above_the_phantom_rejects_deep_junction_rays():
    # rays to the junction co-rotate with a pivoting shaft; insertion depth moves the junction
    # along the shaft, toward the line of sight at the deep end of the working range
    def cond(overrides, depth_m):
        sc = load_scenario("teleop", {**NO_BURSTS, **overrides})
        const = true_constants(sc)
        gt = pivot(sc.motion.R_neutral(), const.rcm_base_m, depth_m, 10.0, np.array([0.0, 1.0, 0.0]), _swing(0.15, 0.1))
        vf = simulate_vision(sensors.kinematics(gt, const), sc, const, np.random.default_rng(0))
        return sc, vf, vf.extra["junction_cond"]

    sc, _, shallow = cond({}, 0.125)
    assert (shallow >= sc.vision.junction_min_sin2).all()
    _, deep_vf, deep = cond({}, 0.155)
    assert (deep < sc.vision.junction_min_sin2).all() and not deep_vf.junction_visible.any()
    _, _, old = cond({"profile": "clean"}, 0.155)
    assert (old >= 0.45).all()  # the clean profile's camera: the test never rejects
