"""Skill-assessment metrics on synthetic profiles with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from services.fusion.skill import kinematics as kin
from services.fusion.skill.assess import (
    METRICS,
    MetricsParams,
    Motion,
    correlated_noise,
    draw_intervals,
    drawn_motion,
    resample,
    segment_metrics,
    sigma_envelope,
)
from services.fusion.skill.smoothness import dimensionless_jerk, ldlj, sparc

RCM = np.array([0.65, 0.0, 0.30])


def test_reference_profile_matches_the_published_implementation():
    # the published implementation's test profile: a Gaussian speed exp(-5 t^2), t = -1..0.99 s, 100 Hz
    t = np.arange(-1.0, 1.0, 0.01)
    v = np.exp(-5.0 * t**2)
    assert sparc(v, 100.0) == pytest.approx(-1.41403, abs=5e-6)
    assert ldlj(v, 100.0) == pytest.approx(-5.81636, abs=5e-6)
    assert dimensionless_jerk(v, 100.0) == pytest.approx(-335.746837, rel=1e-8)


def test_minimum_jerk_movement_is_smooth_and_unchanged_by_its_scale_and_rate():
    def min_jerk_speed(duration_s: float, distance: float, rate_hz: float) -> np.ndarray:
        tau = np.arange(0.0, duration_s + 0.5 / rate_hz, 1.0 / rate_hz) / duration_s
        return distance / duration_s * 30.0 * tau**2 * (1.0 - tau) ** 2

    v = min_jerk_speed(1.0, 0.1, 100.0)
    # analytically: v_peak = 1.875 D / T and the integral of (d2v/dt2)^2 is 720 D^2 / T^5, so the
    # dimensionless jerk is 720 / 1.875^2 = 204.8 whatever D and T
    assert ldlj(min_jerk_speed(1.0, 0.1, 1000.0), 1000.0) == pytest.approx(-np.log(720.0 / 1.875**2), abs=0.01)
    # a single bell-shaped movement: SPARC close to the Gaussian reference profile's
    t = np.arange(-1.0, 1.0, 0.01)
    assert sparc(v, 100.0) == pytest.approx(sparc(np.exp(-5.0 * t**2), 100.0), abs=0.1)
    # LDLJ is dimensionless: the same movement ten times longer in distance, or sampled twice as fast
    assert ldlj(v, 100.0) == pytest.approx(ldlj(min_jerk_speed(1.0, 1.0, 100.0), 100.0), abs=1e-9)
    assert ldlj(v, 100.0) == pytest.approx(ldlj(min_jerk_speed(1.0, 0.1, 200.0), 200.0), abs=0.05)
    # two movements with a stop between them are less smooth than one
    two = np.concatenate([v, v])
    assert ldlj(two, 100.0) < ldlj(v, 100.0) - 1.0
    assert sparc(two, 100.0) < sparc(v, 100.0) - 0.5


def test_added_tremor_lowers_both_smoothness_metrics():
    t = np.arange(-1.0, 1.0, 0.01)
    v = np.exp(-5.0 * t**2)
    shaky = v + 0.05 * np.sin(2 * np.pi * 6.0 * t)
    assert sparc(shaky, 100.0) < sparc(v, 100.0)
    assert ldlj(shaky, 100.0) < ldlj(v, 100.0)


def test_smoothness_refuses_a_profile_without_motion():
    with pytest.raises(ValueError, match="all zero"):
        sparc(np.zeros(50), 100.0)
    with pytest.raises(ValueError, match="no jerk"):
        ldlj(np.full(50, 0.01), 100.0)


def _line(n: int, direction: np.ndarray, length_m: float) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)[:, None]
    start = RCM + 0.14 * np.array([np.sin(0.5), 0.0, -np.cos(0.5)])
    return start + s * length_m * direction


def test_path_and_depth_of_a_straight_insertion():
    u = np.array([np.sin(0.5), 0.0, -np.cos(0.5)])
    p = _line(501, u, 0.02)  # 20 mm straight in along the shaft
    assert kin.path_length(p) == pytest.approx(0.02, rel=1e-9)
    depth, u_est = kin.shaft_coordinates(p, RCM)
    assert kin.path_length(depth) == pytest.approx(0.02, rel=1e-9)
    assert kin.swept_angle(u_est) == pytest.approx(0.0, abs=1e-9)
    straight, fulcrum = kin.economy(p, RCM)
    assert straight == pytest.approx(1.0) and fulcrum == pytest.approx(1.0)


def test_path_and_depth_of_a_circle_about_the_rcm():
    # the tip on a cone about the vertical through the RCM: a circle of radius L sin(a), depth constant
    L, a = 0.14, 0.4
    phi = np.linspace(0.0, 2 * np.pi, 2001)
    p = RCM + L * np.stack([np.sin(a) * np.cos(phi), np.sin(a) * np.sin(phi), -np.cos(a) * np.ones_like(phi)], 1)
    assert kin.path_length(p) == pytest.approx(2 * np.pi * L * np.sin(a), rel=1e-5)
    depth, u = kin.shaft_coordinates(p, RCM)
    assert kin.path_length(depth) == pytest.approx(0.0, abs=1e-12)
    elevation, azimuth = kin.elevation_azimuth(u)
    assert kin.path_length(elevation) == pytest.approx(0.0, abs=1e-9)
    assert kin.path_length(azimuth) == pytest.approx(2 * np.pi, rel=1e-9)
    assert kin.swept_angle(u) == pytest.approx(2 * np.pi * np.sin(a), rel=1e-4)
    straight, fulcrum = kin.economy(p, RCM)  # back to the start: no net progress
    assert straight == pytest.approx(0.0, abs=1e-9) and fulcrum == pytest.approx(0.0, abs=1e-9)


def test_back_and_forth_counts_every_stroke():
    u = np.array([np.sin(0.5), 0.0, -np.cos(0.5)])
    s = np.concatenate([np.linspace(0, 1, 101), np.linspace(1, 0, 101)[1:]] * 3)
    p = RCM + 0.14 * u + 0.01 * s[:, None] * u  # 10 mm in and out, three times
    assert kin.path_length(p) == pytest.approx(0.06, rel=1e-9)
    depth, _ = kin.shaft_coordinates(p, RCM)
    assert kin.path_length(depth) == pytest.approx(0.06, rel=1e-9)
    # a sideways stroke changes the depth only by the second-order lengthening of the lever
    side = np.array([0.0, 1.0, 0.0])
    q = RCM + 0.14 * u + 0.01 * s[:, None] * side
    depth_q, _ = kin.shaft_coordinates(q, RCM)
    assert kin.path_length(q) == pytest.approx(0.06, rel=1e-9)
    assert kin.path_length(depth_q) == pytest.approx(6 * (np.hypot(0.14, 0.01) - 0.14), rel=1e-6)


def test_fulcrum_reference_of_a_pure_pivot_is_the_arc():
    L, a = 0.14, 0.3
    p0 = RCM + L * np.array([0.0, 0.0, -1.0])
    p1 = RCM + L * np.array([np.sin(a), 0.0, -np.cos(a)])
    assert kin.fulcrum_reference_length(p0, p1, RCM) == pytest.approx(L * a, rel=1e-9)
    arc = RCM + L * np.stack([np.sin(np.linspace(0, a, 300)), np.zeros(300), -np.cos(np.linspace(0, a, 300))], 1)
    straight, fulcrum = kin.economy(arc, RCM)
    assert fulcrum == pytest.approx(1.0, rel=1e-4)
    assert straight == pytest.approx(2 * np.sin(a / 2) / a, rel=1e-4)


def test_roll_angle_accumulates_the_twist_about_the_shaft():
    ang = np.concatenate([np.linspace(0, np.pi, 200), np.linspace(np.pi, 0.5, 100)])
    q = np.stack([np.zeros_like(ang), np.zeros_like(ang), np.sin(ang / 2), np.cos(ang / 2)], 1)
    roll = kin.roll_angle(q)
    assert roll[-1] == pytest.approx(0.5, abs=1e-9)
    assert kin.path_length(roll) == pytest.approx(np.pi + (np.pi - 0.5), rel=1e-9)


def test_working_volume_of_a_box():
    rng = np.random.default_rng(1)
    corners = np.array([[x, y, z] for x in (0, 0.02) for y in (0, 0.01) for z in (0, 0.03)])
    inside = rng.uniform([0, 0, 0], [0.02, 0.01, 0.03], size=(200, 3))
    assert kin.working_volume(np.vstack([corners, inside])) == pytest.approx(0.02 * 0.01 * 0.03, rel=1e-9)
    assert kin.working_volume(corners[:, :2].repeat(2, 0).reshape(-1, 2) @ np.eye(2, 3)) == 0.0  # flat


def test_idle_time_and_movements_on_a_constructed_speed_profile():
    rate = 100.0
    v = np.zeros(1000)  # 10 s
    v[100:300] = 0.02  # 2 s movement
    v[350:380] = 0.02  # 0.3 s: a movement at the minimum duration
    v[500:510] = 0.02  # 0.1 s: too short
    v[600:700] = 0.02  # two runs 0.05 s apart: one movement
    v[705:800] = 0.02
    assert kin.idle_time(v, rate, 0.005) == pytest.approx((1000 - 200 - 30 - 10 - 100 - 95) / rate)
    moves = kin.movements(v, rate, 0.005, min_duration_s=0.3, merge_gap_s=0.1)
    assert moves == [(100, 300), (350, 380), (600, 800)]
    assert kin.movements(v, rate, 0.005, min_duration_s=0.3, merge_gap_s=0.0) == [
        (100, 300),
        (350, 380),
        (600, 700),
        (705, 800),
    ]


def _motion(p: np.ndarray, rate: float, sigma_m: float | None = None) -> Motion:
    n = len(p)
    return Motion(
        np.arange(n) / rate, p, np.zeros(n), RCM,
        None if sigma_m is None else np.full((n, 3), sigma_m), None if sigma_m is None else np.full(n, 1e-3),
    )  # fmt: skip


def _pivot_and_stop(rate: float) -> np.ndarray:
    """A minimum-jerk pivot of 0.3 rad about the RCM in 2 s, then 3 s still."""
    t = np.arange(0.0, 5.0, 1.0 / rate)
    tau = np.clip(t / 2.0, 0.0, 1.0)
    a = 0.3 * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    return RCM + 0.14 * np.stack([np.sin(a), np.zeros_like(a), -np.cos(a)], 1)


def test_segment_metrics_of_a_single_pivot():
    params = MetricsParams()
    m = segment_metrics(_motion(_pivot_and_stop(100.0), 100.0), params)
    assert set(m) == set(METRICS)
    assert m["duration_s"] == pytest.approx(5.0)
    assert m["path_length_mm"] == pytest.approx(0.14 * 0.3 * 1e3, rel=0.01)
    assert m["angular_path_deg"] == pytest.approx(np.rad2deg(0.3), rel=0.01)
    assert m["elevation_path_deg"] == pytest.approx(np.rad2deg(0.3), rel=0.01)
    assert m["depth_path_mm"] < 0.1  # the pivot keeps the depth; the low-pass bends it a little
    assert m["economy_fulcrum"] == pytest.approx(1.0, rel=0.01)
    assert m["economy_straight"] == pytest.approx(2 * np.sin(0.15) / 0.3, rel=0.01)
    assert m["movements"] == 1
    assert 3.0 < m["idle_time_s"] < 3.8  # the still end and the slow start and finish of the move
    assert m["peak_speed_mmps"] == pytest.approx(1.875 * 0.14 * 0.3 / 2.0 * 1e3, rel=0.03)


def test_a_segment_shorter_than_the_metrics_need_is_refused():
    with pytest.raises(ValueError, match="at least 2 s"):
        segment_metrics(_motion(_pivot_and_stop(100.0)[:150], 100.0), MetricsParams())


def test_correlated_noise_is_the_stated_second_order_gauss_markov_process():
    corner_hz = 0.4
    z = correlated_noise(np.random.default_rng(3), 200_000, 1, 100.0, corner_hz)[:, 0]
    assert z.var() == pytest.approx(1.0, rel=0.05)
    tc = 1.0 / (2 * np.pi * corner_hz)  # autocorrelation (1 + lag / tc) exp(-lag / tc)
    for lag_s in (0.5 * tc, tc, 2.0 * tc):
        lag = int(round(lag_s * 100.0))
        want = (1 + lag / 100.0 / tc) * np.exp(-lag / 100.0 / tc)
        assert np.mean(z[:-lag] * z[lag:]) / z.var() == pytest.approx(want, abs=0.03)


def test_sigma_envelope_keeps_the_level_and_drops_the_sawtooth():
    t = np.arange(3000) / 100.0
    saw = 1e-3 + 4e-3 * ((t * 5.0) % 1.0)  # a filter's sigma between 5 Hz fixes: 1 to 5 mm
    env = sigma_envelope(saw, 100.0, 1.0)
    assert np.allclose(env[300:-300], np.sqrt(np.mean(saw**2)), rtol=0.01)
    step = np.where(t < 15.0, 1e-3, 3e-3)  # a slow change in the sigma is kept
    env = sigma_envelope(step, 100.0, 1.0)
    assert env[500] == pytest.approx(1e-3, rel=0.01) and env[2500] == pytest.approx(3e-3, rel=0.01)


def test_drawn_errors_carry_no_jerk_from_the_sigmas_sawtooth():
    # the drawn errors must be as jerky as the stated error model, whatever the sigma does between a
    # filter's measurements: drawn from the raw sawtooth, their jerk was thousands of times that of a
    # constant sigma at the same RMS, and LDLJ's interval lay wholly above the truth on the bench
    t = np.arange(3000) / 100.0
    saw = 1e-3 + 4e-3 * ((t * 5.0) % 1.0)
    params = MetricsParams()

    def jerk(sigma: np.ndarray) -> float:
        p = np.tile(RCM + [0.0, 0.0, -0.14], (len(t), 1))
        m = Motion(t, p, np.zeros(len(t)), RCM, np.stack([sigma] * 3, 1), np.full(len(t), 1e-3))
        rng = np.random.default_rng(0)
        out = []
        for _ in range(20):
            e = kin.lowpass(drawn_motion(m, rng, params).p_tip_base_m - p, 100.0, params.speed_cutoff_hz)
            out.append(np.mean(np.diff(e, 3, axis=0) ** 2))
        return float(np.mean(out))

    ratio = jerk(saw) / jerk(np.full(len(t), np.sqrt(np.mean(saw**2))))
    assert 0.8 < ratio < 1.25


def test_intervals_shrink_to_the_value_with_the_sigma_and_widen_with_it():
    p = _pivot_and_stop(100.0)
    params = MetricsParams(draws=40)
    narrow_m = _motion(p, 100.0, sigma_m=1e-5)
    wide_m = _motion(p, 100.0, sigma_m=1e-3)
    point = segment_metrics(narrow_m, params)
    narrow = draw_intervals(narrow_m, point, params)
    wide = draw_intervals(wide_m, point, params)
    # a 0.01 mm sigma: an interval of a few thousandths of a degree about the value
    lo, hi = narrow["angular_path_deg"]
    assert abs(lo - point["angular_path_deg"]) < 0.02 and abs(hi - point["angular_path_deg"]) < 0.02
    assert (
        wide["path_length_mm"][1] - wide["path_length_mm"][0]
        > narrow["path_length_mm"][1] - narrow["path_length_mm"][0]
    )
    assert draw_intervals(_motion(p, 100.0), point, params) == {}  # no sigmas: no interval


def test_an_interval_is_the_draws_spread_about_the_value_not_their_shift():
    # drawn errors lengthen the path whichever way they point; the interval is their spread placed
    # about the estimate's value, not shifted by that lengthening (reflected about the value, the
    # path's interval lay below it, and LDLJ's above, wherever the draws' shift exceeded their spread)
    p = _pivot_and_stop(100.0)
    params = MetricsParams(draws=40)
    m = _motion(p, 100.0, sigma_m=3e-3)
    point = segment_metrics(m, params)
    bounds = draw_intervals(m, point, params)
    rng = np.random.default_rng(0)
    drawn = [segment_metrics(drawn_motion(m, rng, params), params) for _ in range(params.draws)]
    for key in ("path_length_mm", "ldlj"):
        vals = np.array([d[key] for d in drawn])
        # the draws shift it by more than half their spread: reflected, the interval would miss the value
        assert abs(np.median(vals) - point[key]) > 0.5 * (bounds[key][1] - bounds[key][0])
        lo, hi = bounds[key]
        assert lo < point[key] < hi
        assert hi - lo == pytest.approx(np.quantile(vals, 0.975) - np.quantile(vals, 0.025), rel=1e-9)


def test_drawn_errors_lie_along_and_across_the_shaft_at_their_own_sizes():
    n = 20_000
    u = np.array([0.0, 0.6, -0.8])
    m = Motion(np.arange(n) / 100.0, np.tile(RCM + 0.14 * u, (n, 1)), np.zeros(n), RCM, np.full((n, 3), 2e-3), None)
    params = MetricsParams(depth_scale_sd=0.0)
    d = drawn_motion(m, np.random.default_rng(1), params).p_tip_base_m - m.p_tip_base_m
    along = d @ u
    across = d - along[:, None] * u
    assert np.std(along) == pytest.approx(params.depth_sigma_scale * 2e-3, rel=0.1)
    assert np.sqrt(np.mean(np.sum(across**2, 1)) / 2) == pytest.approx(params.sigma_scale * 2e-3, rel=0.1)


def _depth_strokes(duration_s: float, rate: float) -> np.ndarray:
    """The tip moved slowly in and out along one shaft direction: 2 + 1 mm of depth at 0.3 and 0.47 Hz."""
    t = np.arange(0.0, duration_s, 1.0 / rate)
    depth = 0.14 + 0.002 * np.sin(2 * np.pi * 0.3 * t) + 0.001 * np.sin(2 * np.pi * 0.47 * t + 1.0)
    u = np.array([0.0, 0.3, -1.0]) / np.hypot(0.3, 1.0)
    return RCM + depth[:, None] * u


def test_the_depth_paths_interval_takes_off_what_the_estimates_error_added():
    # an estimate's depth error lengthens the depth path whichever way it points: an interval about
    # the estimate's value lay above the truth (on the bench the estimate's depth path was 13.5 mm
    # long on average, half the segments' truths outside); the interval takes off the path the
    # draws add, which is what the estimate's own error of the same size added
    truth = _depth_strokes(60.0, 100.0)
    params = MetricsParams(draws=40, depth_scale_sd=0.0)
    true_path = segment_metrics(_motion(truth, 100.0), params)["depth_path_mm"]
    u = (truth - RCM) / np.linalg.norm(truth - RCM, axis=1)[:, None]
    for seed in range(3):
        z = correlated_noise(np.random.default_rng(100 + seed), len(truth), 1, 100.0, params.error_corner_hz)
        m = _motion(truth + params.depth_sigma_scale * 4e-3 * z * u, 100.0, sigma_m=4e-3)
        x = segment_metrics(m, params)["depth_path_mm"]
        lo, hi = draw_intervals(m, {"depth_path_mm": x}, params)["depth_path_mm"]
        assert x > true_path + 10.0  # the error's lengthening, more than a third of the interval
        assert lo <= true_path <= hi
        assert (lo + hi) / 2 < x - 0.5 * (x - true_path)


def test_the_roll_paths_interval_holds_the_gyros_scale_error():
    # roll about the shaft is the gyro's alone: its scale-factor error scales the roll path, which
    # no sigma of the stream carries (on the bench the roll path's error was its rate's 0.1-0.25 %)
    t = np.arange(0.0, 20.0, 0.01)
    roll = np.deg2rad(60.0) * np.sin(2 * np.pi * 0.4 * t)
    p = np.tile(RCM + [0.0, 0.0, -0.14], (len(t), 1))
    params = MetricsParams(draws=40)
    truth = segment_metrics(Motion(t, p, roll, RCM), params)["roll_path_deg"]
    m = Motion(t, p, roll * 1.003, RCM, np.full((len(t), 3), 1e-3), np.full(len(t), np.deg2rad(0.2)))
    point = segment_metrics(m, params)
    lo, hi = draw_intervals(m, point, params)["roll_path_deg"]
    assert point["roll_path_deg"] - truth == pytest.approx(0.003 * truth, rel=0.05)
    assert lo <= truth <= hi
    assert hi - lo > 2 * 1.5 * params.roll_scale_sd * truth


def test_resample_puts_two_streams_on_one_grid():
    t_a = np.array([0, 4_000_000, 11_000_000, 20_000_000, 31_000_000], np.int64) + 5_000_000
    x = np.linspace(0, 1, 5)[:, None] * np.ones((1, 3))
    m = resample(t_a, x, np.zeros(5), RCM, 100.0, t0_ns=0)
    assert np.allclose(m.t_s, [0.01, 0.02, 0.03])
    assert np.allclose(m.p_tip_base_m[:, 0], np.interp([10e6, 20e6, 30e6], t_a, x[:, 0]))
