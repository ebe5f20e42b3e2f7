"""The gyro link between a trial's two stationary windows, and its blend with the filter's own
post-window attitude (the relative rotation the rotation protocol scores)."""

from __future__ import annotations

import dataclasses

import numpy as np

from study.static_filter import StaticParams
from study.static_trials import _blend_gyro, gyro_link
from tiplog.geometry import rotation_angle, so3_exp

W = np.array([0.3, -0.2, 0.5])  # rad/s, IMU axes
BIAS = np.array([0.002, -0.001, 0.003])


def _stream(seconds: float = 2.0, rate_hz: float = 200.0):
    t = np.arange(0, int(seconds * rate_hz) + 1) * int(1e9 / rate_hz)
    return t.astype(np.int64), np.tile(W + BIAS, (len(t), 1))


def test_gyro_link_integrates_between_the_windows_with_the_bias_removed():
    t, w = _stream()
    G = gyro_link(t, w, t[10], t[310], BIAS)  # samples 11..310: 299 intervals of 5 ms
    assert np.allclose(G, so3_exp(W * 299 * 0.005), atol=1e-9)
    assert np.allclose(gyro_link(t, w, t[10], t[11], BIAS), np.eye(3))  # fewer than two samples


def test_gyro_link_walks_the_bias_between_the_two_rest_rates_where_the_tool_turned():
    """Still for a second, then turning at W for a second while the bias moves from BIAS to b1
    evenly over the turn (a walk that moves only in motion); the sample at index i is held over
    [t_i, t_i+1], and the link spans t_0 to t_400."""
    t = (np.arange(401) * 5_000_000).astype(np.int64)  # 200 Hz, 2 s
    b1 = BIAS + np.array([0.01, -0.02, 0.015])  # rad/s: 0.6-1.1 deg/s, far above a rest's noise
    i = np.arange(401)
    turning = (i >= 200)[:, None]
    frac = np.clip((i - 200 + 0.5) / 200, 0.0, 1.0)[:, None]  # of the change, mid-interval
    w = np.where(turning, W + BIAS + frac * (b1 - BIAS), BIAS)
    truth = so3_exp(W * 200 * 0.005)
    walk = (0.0, np.radians(0.35))  # no walk at rest: the bias moves only while the tool turns
    err = {
        "pinned": gyro_link(t, w, t[0], t[400], BIAS, b1, walk),
        "held": gyro_link(t, w, t[0], t[400], BIAS),  # W_pre's rate throughout
        "in time": gyro_link(t, w, t[0], t[400], BIAS, b1, (np.radians(1.0), 0.0)),  # walking with time alone
    }
    err = {k: np.degrees(rotation_angle(G.T @ truth)) for k, G in err.items()}
    # pinned: exact but for |w| varying by a few % over the turn (the walk's rate goes with |w|^2)
    assert err["pinned"] < 0.05 and err["held"] > 0.6 and err["in time"] > 0.3, err


def test_blend_moves_the_post_attitude_towards_the_gyro_link_less_for_larger_turns():
    t, w = _stream(seconds=4.0)
    M = so3_exp(np.radians([1.0, -2.0, 30.0]))  # R_tool_imu
    Rp = so3_exp(np.array([0.1, 0.4, -0.2]))
    prm = StaticParams()

    def blend(t1_idx, **kw):
        G = M @ gyro_link(t, w, t[0], t[t1_idx], BIAS) @ M.T
        Rq = Rp @ G @ so3_exp(np.radians([0.5, -0.3, 0.2]))  # the filter ended 0.6 deg off the link
        out = _blend_gyro(Rp, Rq, t, w, t[0], t[t1_idx], BIAS, M, dataclasses.replace(prm, **kw))
        return Rq, Rp @ G, out

    Rq, Rg, out = blend(20, relrot_absolute_deg=0.0)
    assert np.allclose(out, Rq)  # off: the filter's own attitude
    Rq, Rg, out = blend(20, relrot_gyro_per_deg=0.0)
    assert np.allclose(out, Rg)  # a perfect gyro: the link alone
    moved = []
    for k in (20, 200, 700):  # 3, 33 and 117 deg turned
        Rq, Rg, out = blend(k)
        gap = rotation_angle(Rq.T @ Rg)
        assert np.isclose(rotation_angle(Rq.T @ out) + rotation_angle(out.T @ Rg), gap, atol=1e-9)  # on the geodesic
        moved.append(rotation_angle(Rq.T @ out) / gap)
    assert moved[0] > 0.95 and moved[0] > moved[1] > moved[2] > 0.0, moved
