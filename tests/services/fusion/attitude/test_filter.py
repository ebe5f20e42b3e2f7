"""The six-axis attitude filter on synthetic IMU data with a known orientation: accuracy under
motion and gyro bias, any rate and dropped rows, gaps, missing values, online equals batch,
and beside the vqf package on the same data."""

from __future__ import annotations

import numpy as np
import pytest

from services.fusion.attitude import filter as attitude
from services.fusion.attitude.filter import AttitudeFilter, Params, estimate
from services.fusion.attitude.offline import smooth
from tiplog.geometry import quat_to_rot, so3_exp

G = 9.81


def _truth(duration_s: float, seed: int, rate_hz: float = 1000.0):
    """Fine-grid truth: stamps (N,), R_earth_sensor (N, 3, 3), body rate (N, 3) rad/s,
    specific force (N, 3) m/s^2. Rotation: sines on three axes; translation: sines of a few cm."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    amp = np.radians(rng.uniform(20, 60, 3))  # deg/s
    f = rng.uniform(0.2, 1.2, 3)
    ph = rng.uniform(0, 2 * np.pi, 3)
    w = amp * np.sin(2 * np.pi * f * t[:, None] + ph)
    R = np.empty((t.size, 3, 3))
    R[0] = so3_exp(np.radians([20.0, -10.0, 30.0]))
    steps = so3_exp(0.5 * (w[1:] + w[:-1]) / rate_hz)
    for i in range(1, t.size):
        R[i] = R[i - 1] @ steps[i - 1]
    fa, pa = rng.uniform(0.5, 2.0, 3), rng.uniform(0, 2 * np.pi, 3)
    a_earth = 0.03 * (2 * np.pi * fa) ** 2 * -np.sin(2 * np.pi * fa * t[:, None] + pa)  # 3 cm sines
    f_sensor = np.einsum("nji,nj->ni", R, a_earth + [0.0, 0.0, G])
    return t, R, w, f_sensor


def _sample(truth, rate_hz: float, seed: int, bias_dps=(0.5, -0.3, 0.2), jitter=0.0, drop=0.0):
    t, R, w, f = truth
    rng = np.random.default_rng(seed + 1)
    ts = np.arange(t[0], t[-1], 1.0 / rate_hz)
    ts = np.sort(ts + rng.uniform(-jitter, jitter, ts.size) / rate_hz)
    ts = ts[(ts >= t[0]) & (ts <= t[-1])]
    if drop:
        ts = ts[rng.random(ts.size) >= drop]
    idx = np.clip(np.searchsorted(t, ts), 0, t.size - 1)
    gyr = _mean_rate(truth, idx) + np.radians(bias_dps) + rng.normal(0, np.radians(0.1), (ts.size, 3))
    acc = f[idx] + rng.normal(0, 0.05, (ts.size, 3))
    return t[idx], gyr, acc, R[idx]


def _mean_rate(truth, idx: np.ndarray) -> np.ndarray:
    """Each sample the mean body rate over the step that ends at its stamp (the first: the rate
    there), as a MEMS gyroscope's decimation filter gives it; idx indexes the fine grid."""
    t, _, w, _ = truth
    turned = np.vstack([np.zeros(3), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t)[:, None], axis=0)])
    out = w[idx].copy()
    dt = t[idx[1:]] - t[idx[:-1]]
    ok = dt > 0
    out[1:][ok] = (turned[idx[1:]] - turned[idx[:-1]])[ok] / dt[ok, None]
    return out


def _incl_err_deg(q_wxyz: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    R_est = quat_to_rot(q_wxyz[:, [1, 2, 3, 0]])
    up_est, up_true = R_est[:, 2, :], R_true[:, 2, :]
    return np.degrees(np.arccos(np.clip((up_est * up_true).sum(-1), -1, 1)))


@pytest.fixture(scope="module")
def truth():
    return _truth(60.0, seed=5)


def test_inclination_under_motion_and_bias(truth):
    t, gyr, acc, R = _sample(truth, 200.0, seed=1)
    err = _incl_err_deg(estimate(t, gyr, acc), R)[t > 20]
    assert np.sqrt(np.mean(err**2)) < 1.0
    # the bias is estimated: the same run without it drifts further
    err_nb = _incl_err_deg(estimate(t, gyr, acc, Params(estimate_bias=False)), R)[t > 20]
    assert np.sqrt(np.mean(err**2)) < np.sqrt(np.mean(err_nb**2))
    f = AttitudeFilter()
    f.update_batch(t, gyr, acc)
    assert np.degrees(np.linalg.norm(f.bias_radps - np.radians([0.5, -0.3, 0.2]))) < 0.2


@pytest.mark.parametrize("rate_hz,jitter,drop", [(100.0, 0.0, 0.0), (833.0, 0.3, 0.0), (200.0, 0.2, 0.2)])
def test_any_rate_jitter_and_dropped_rows(truth, rate_hz, jitter, drop):
    t, gyr, acc, R = _sample(truth, rate_hz, seed=2, jitter=jitter, drop=drop)
    err = _incl_err_deg(estimate(t, gyr, acc), R)[t > 20]
    assert np.sqrt(np.mean(err**2)) < 1.0


def test_online_equals_batch_and_pieces(truth):
    t, gyr, acc, _ = _sample(truth, 200.0, seed=3)
    t, gyr, acc = t[:1500], gyr[:1500], acc[:1500]
    whole = estimate(t, gyr, acc)
    f = AttitudeFilter()
    pieces = np.concatenate(
        [f.update_batch(t[:700], gyr[:700], acc[:700]), f.update_batch(t[700:], gyr[700:], acc[700:])]
    )
    g = AttitudeFilter()
    online = np.array([g.update(t[i], gyr[i], acc[i]) for i in range(900)])
    np.testing.assert_array_equal(pieces, whole)
    np.testing.assert_allclose(online, whole[:900], atol=1e-12)


@pytest.mark.skipif(not attitude.HAVE_NUMBA, reason="numba not installed")
def test_compiled_and_plain_python_agree(truth):
    t, gyr, acc, _ = _sample(truth, 200.0, seed=4)
    n = 600
    prm = Params(gyr_delay_s=0.004).vector()
    outs = []
    for kernel in (attitude._run, attitude._run.py_func):
        f = AttitudeFilter()
        q, b = np.empty((n, 4)), np.empty((n, 12))
        kernel(t[:n].copy(), gyr[:n].copy(), acc[:n].copy(), prm, f._st, q, b, f._rest, f._rest_k)
        outs.append(np.hstack([q, b]))
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-9)


def test_missing_values_and_repeated_stamps(truth):
    t, gyr, acc, R = _sample(truth, 200.0, seed=6)
    gyr, acc = gyr.copy(), acc.copy()
    rng = np.random.default_rng(7)
    acc[rng.random(t.size) < 0.3] = np.nan  # accelerometer at a lower rate, as real logs have
    gyr[rng.random(t.size) < 0.05, 1] = np.nan
    t = t.copy()
    t[100] = t[99]
    q = estimate(t, gyr, acc)
    assert np.isfinite(q).all()
    np.testing.assert_array_equal(q[100], q[99])
    assert np.sqrt(np.mean(_incl_err_deg(q, R)[t > 20] ** 2)) < 1.0


def test_gap_restarts_inclination(truth):
    t, gyr, acc, R = _sample(truth, 200.0, seed=8)
    keep = (t < 25) | (t > 28)  # three seconds of rotation lost
    t, gyr, acc, R = t[keep], gyr[keep], acc[keep], R[keep]
    err = _incl_err_deg(estimate(t, gyr, acc), R)
    # the stale orientation is dropped and the inclination comes back from gravity alone
    assert np.sqrt(np.mean(err[(t > 35) & (t < 45)] ** 2)) < 1.5


def test_bad_params_name_the_field():
    with pytest.raises(ValueError, match="tau_acc_s"):
        Params(tau_acc_s=-1.0)


def test_as_good_as_vqf(truth):
    vqf = pytest.importorskip("vqf")
    t, gyr, acc, R = _sample(truth, 200.0, seed=9)
    ours = _incl_err_deg(estimate(t, gyr, acc), R)[t > 20]
    ref_q = vqf.VQF(1 / 200.0).updateBatch(np.ascontiguousarray(gyr), np.ascontiguousarray(acc))["quat6D"]
    ref = _incl_err_deg(ref_q, R)[t > 20]
    assert np.sqrt(np.mean(ours**2)) <= 1.1 * np.sqrt(np.mean(ref**2)) + 0.02


def test_a_gyro_sample_turns_the_step_that_ends_at_its_stamp():
    """A sample is the mean rate over the step before its stamp (as VQF and a MEMS gyroscope's
    decimation filter have it): a turn about the vertical shows in full at the stamp of its
    last sample, not half a step later, online and offline; a missing sample holds the last."""
    t = np.arange(0.0, 3.0, 0.01)
    gyr = np.zeros((t.size, 3))
    gyr[100:200, 2] = np.radians(90.0)  # 90 deg/s over the steps ending at rows 100..199
    acc = np.tile([0.0, 0.0, G], (t.size, 1))
    want = 90.0 * np.clip(t - t[99], 0.0, 1.0)
    p = Params(estimate_bias=False)
    for gyr_in in (gyr, np.where(np.arange(t.size)[:, None] == 150, np.nan, gyr)):
        for q in (estimate(t, gyr_in, acc, p), smooth(t, gyr_in, acc, p)):
            yaw = np.degrees(2.0 * np.arctan2(q[:, 3], q[:, 0]))
            np.testing.assert_allclose(yaw, want, atol=1e-6)


def _delayed(truth, delay_s: float, seed: int):
    """As _sample at 200 Hz, but each gyro sample describes the step that ended delay_s before
    its stamp."""
    t_f = truth[0]
    t, gyr, acc, R = _sample(truth, 200.0, seed=seed)
    now = np.clip(np.searchsorted(t_f, t), 0, t_f.size - 1)
    idx = np.clip(np.searchsorted(t_f, t - delay_s), 0, t_f.size - 1)
    return t, gyr - _mean_rate(truth, now) + _mean_rate(truth, idx), acc, R


def test_gyro_delay_is_undone_online_and_offline(truth):
    t, gyr, acc, R = _delayed(truth, 0.008, seed=10)
    rms = {}
    for d in (0.0, 0.008):
        p = Params(gyr_delay_s=d)
        rms[d] = [np.sqrt(np.mean(_incl_err_deg(f(t, gyr, acc, p), R)[t > 20] ** 2)) for f in (estimate, smooth)]
    assert rms[0.008][0] < 0.8 * rms[0.0][0]
    assert rms[0.008][1] < 0.8 * rms[0.0][1]
    with pytest.raises(ValueError, match="gyr_delay_s"):
        Params(gyr_delay_s=-0.001)


def test_smooth_beats_online_and_keeps_rows(truth):
    t, gyr, acc, R = _sample(truth, 200.0, seed=11)
    online = np.sqrt(np.mean(_incl_err_deg(estimate(t, gyr, acc), R)[t > 20] ** 2))
    offline_err = _incl_err_deg(smooth(t, gyr, acc), R)
    # offline has the future too: no settling at the start and less error after it
    assert np.sqrt(np.mean(offline_err[t > 20] ** 2)) < 0.8 * online
    assert np.sqrt(np.mean(offline_err[t < 5] ** 2)) < 1.0
    # a gap, a missing row of each sensor and a repeated stamp: every row still gets an orientation
    keep = (t < 25) | (t > 28)
    t, gyr, acc, R = t[keep].copy(), gyr[keep].copy(), acc[keep].copy(), R[keep]
    gyr[3000] = np.nan
    acc[3100] = np.nan
    t[3200] = t[3199]
    q = smooth(t, gyr, acc)
    assert q.shape == (t.size, 4) and np.isfinite(q).all()
    np.testing.assert_array_equal(q[3200], q[3199])
    assert np.sqrt(np.mean(_incl_err_deg(q, R)[t > 20] ** 2)) < 1.0


def test_rest_is_the_tracking_filters_detector_and_measures_the_bias():
    """Still, with a bias: rest comes once the detector has released a chunk (the tracking
    filter's `kernels.rest.rest_sample`, fed the same samples), and the bias converges to the truth;
    a slow turn beyond the bias clip is not rest."""
    from services.fusion.eskf.kernels.rest import rest_init, rest_sample

    rng = np.random.default_rng(12)
    rate = 200.0
    t = np.arange(0.0, 20.0, 1.0 / rate)
    bias = np.radians([0.4, -0.2, 0.3])
    gyr = bias + rng.normal(0, np.radians(0.1), (t.size, 3))
    acc = np.array([0.0, 3.0, 9.34]) + rng.normal(0, 0.05, (t.size, 3))
    f = AttitudeFilter()
    flags = np.array([(f.update(t[i], gyr[i], acc[i]), f.rest)[1] for i in range(t.size)])
    rest, k = rest_init(), Params().rest_vector()
    first_release = None
    for i in range(t.size):
        if rest_sample(rest, gyr[i], t[i], 0, k) and first_release is None:
            first_release = i
        rest_sample(rest, acc[i], t[i], 1, k)
    assert first_release is not None and not flags[:first_release].any() and flags[first_release:].all()
    assert np.degrees(np.abs(f.bias_radps - bias)).max() < 0.02
    turn = AttitudeFilter()
    up = acc.mean(axis=0) / np.linalg.norm(acc.mean(axis=0))
    turn.update_batch(t, gyr + np.radians(3.0) * up, acc)  # 3 deg/s about the vertical: gravity stays put
    assert not turn.rest
