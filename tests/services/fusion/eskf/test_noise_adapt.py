"""Innovation-based noise matching (`TrackingFilter._adapt`): a vision stream noisier than the
filter assumes is weighed less instead of being gated out frame after frame, one as noisy as
assumed keeps its variance, a stream far beyond any plausible noise is set aside and returns
when it is consistent again, and a reset keeps what the innovations taught."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.fusion.eskf.filter import ADAPTIVE, TrackingFilter
from services.fusion.eskf.params import Params
from tests.services.fusion.eskf.test_filter import G, _calib, _obs, _pose


def _static(seconds: float, tilt_sd_deg, params: Params | None = None, seed: int = 3, f=None, s=None):
    """A tool at rest, vision every 13th gyro sample with one tangent plane tilted by white noise
    of `tilt_sd_deg` (a number, or a function of the time in s); returns (filter, state, R, p)."""
    c = _calib()
    R, p = _pose()
    f = f or TrackingFilter(c, params or Params())
    rng = np.random.default_rng(seed)
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    if s is None:
        s = f.init_from_vision(0, _obs(c, R, p), f_true)
    t0 = s.t_ns
    sd = tilt_sd_deg if callable(tilt_sd_deg) else (lambda _t, v=tilt_sd_deg: v)
    for k in range(1, int(seconds * 200)):
        t = t0 + k * 5_000_000
        f.on_gyro(s, t, rng.normal(size=3) * 0.003)
        if k % 5 == 0:
            f.on_accel(s, t + 1000, f_true + rng.normal(size=3) * 0.05)
        if k % 13 == 0:
            f.propagate(s, t + 2000)
            f.update_vision(s, _obs(c, R, p, tilt_rad=math.radians(rng.normal() * sd(k * 0.005))))
    return f, s, R, p


def _share_rejected(s) -> float:
    applied = s.counts.get("updates:vision_axis", 0)
    rejected = s.counts.get("rejected:vision_axis:innovation", 0)
    return rejected / max(applied + rejected, 1)


def test_a_plane_as_noisy_as_assumed_keeps_its_variance():
    _, s, _, _ = _static(20.0, Params().vision_plane_sigma_deg)
    assert s.noise[ADAPTIVE["vision_axis"], 0] < 1.5
    assert _share_rejected(s) < 0.01


def test_a_plane_four_times_noisier_is_weighed_less_instead_of_gated_out():
    sigma = 4 * Params().vision_plane_sigma_deg
    _, off, _, _ = _static(20.0, sigma, Params(noise_adapt_tau_s=0.0))
    _, on, R, p = _static(20.0, sigma)
    lam = on.noise[ADAPTIVE["vision_axis"], 0]
    assert 4.0 < lam < 40.0, lam  # the variance of a plane 4x noisier: 16x, on half the rows
    assert _share_rejected(off) > 0.05, _share_rejected(off)
    assert _share_rejected(on) < 0.25 * _share_rejected(off), (_share_rejected(on), _share_rejected(off))
    assert not on.noise[:, 2].any()  # nothing set aside
    assert np.linalg.norm(on.p - p) < 1e-3


def test_one_gross_outlier_moves_the_factor_little():
    f, s, R, p = _static(5.0, Params().vision_plane_sigma_deg)
    i = ADAPTIVE["vision_axis"]
    before, last = s.noise[i, 0], s.noise[i, 1]
    s.t_ns += 66_000_000
    f.update_vision(s, _obs(f.c, R, p, tilt_rad=math.radians(1.2)))  # gated out on innovation
    assert s.counts["rejected:vision_axis:innovation"] >= 1
    # at most a = dt / 3 s of the capped z = 18.47 / 4
    a = (s.t_ns - last) * 1e-9 / Params().noise_adapt_tau_s
    assert before < s.noise[i, 0] <= before * (1 + a * (18.47 / 4 - 1)) + 1e-9


def test_a_stream_far_beyond_its_noise_is_set_aside_and_returns_when_consistent():
    sigma = Params().vision_plane_sigma_deg
    prm = Params(noise_adapt_max=20.0)  # a ceiling a plane 12x noisier reaches (its frames that pass the trocar gate)
    f, s, R, p = _static(40.0, lambda t: 12 * sigma if t < 20.0 else sigma, prm)
    i = ADAPTIVE["vision_axis"]
    assert s.counts.get("set_aside:vision_axis", 0) >= 1
    assert s.counts.get("rejected:vision_axis:set_aside", 0) > 0
    assert s.counts.get("returned:vision_axis", 0) >= 1
    assert s.noise[i, 2] == 0.0 and s.noise[i, 0] < 0.5 * prm.noise_adapt_max


def test_the_noise_factors_reach_the_diagnostics_and_survive_a_reset():
    from services.fusion.timing.runner import FusionRunner

    r = FusionRunner(_calib(), Params())
    f, s, _, _ = _static(10.0, 4 * Params().vision_plane_sigma_deg, f=r.filt)
    r._track.state = s
    d = r.diagnostics()
    assert d["noise_scale"]["vision_axis"] == s.noise[ADAPTIVE["vision_axis"], 0] > 2.0
    assert d["aside"] == [] and d["set_aside"] == {}
    # a reset: the next state starts from the discarded state's factors
    r._track.noise = s.noise.copy()
    R, p = _pose()
    fresh = r.filt.init_from_vision(s.t_ns, _obs(r.calib, R, p), None)
    r._carry_noise(fresh)
    assert fresh.noise[ADAPTIVE["vision_axis"], 0] == s.noise[ADAPTIVE["vision_axis"], 0]
    assert np.isnan(fresh.noise[:, 1]).all()


def _tip_step(power: float, factor: float):
    """One vision frame whose junction lies 2 mm deeper than a settled state's, with the tip's
    factor set to `factor`: the state before, and after it under `noise_adapt_tip_power`."""
    f, s, R, p = _static(3.0, Params().vision_plane_sigma_deg)
    f = TrackingFilter(f.c, Params(noise_adapt_tip_power=power))
    s.noise[ADAPTIVE["vision_tip"], 0] = factor
    after = s.copy()
    after.t_ns += 66_000_000
    f.propagate(after, after.t_ns)
    f.update_vision(after, _obs(f.c, R, p + 0.002 * R[:, 2]))  # the shaft along itself: the planes as before
    return s, after, R


def test_the_tip_is_weighed_with_its_factor_to_a_power_and_its_factor_learns_as_before():
    i = ADAPTIVE["vision_tip"]
    s, one, R = _tip_step(1.0, 4.0)
    _, three, _ = _tip_step(3.0, 4.0)
    n = s.counts["updates:vision_tip"]
    assert one.counts["updates:vision_tip"] == three.counts["updates:vision_tip"] == n + 1
    moved_one = (one.p - s.p) @ R[:, 2]
    moved_three = (three.p - s.p) @ R[:, 2]
    assert 0.0 < moved_three < 0.5 * moved_one  # 64 instead of 4 times the tip's variance
    # the factor follows the NIS under 4 R in both: the power changes the weight, not what is learnt
    assert three.noise[i, 0] == pytest.approx(one.noise[i, 0], rel=1e-9)
    assert one.noise[i, 0] != 4.0
    # a tip as noisy as assumed (factor 1): the power changes nothing
    _, a, _ = _tip_step(1.0, 1.0)
    _, b, _ = _tip_step(3.0, 1.0)
    assert np.array_equal(a.p, b.p) and np.array_equal(a.P, b.P)
