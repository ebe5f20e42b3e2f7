"""The real-against-bench IMU statistics on synthetic data of known noise, vibration and scale."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import imu_real_vs_bench as irb
from tiplog.geometry import so3_exp


def test_allan_fit_recovers_white_density_and_random_walk():
    rate, n_density, k_walk = 200.0, 0.01, 0.004  # units/rtHz, units*rtHz
    rng = np.random.default_rng(3)
    segs = []
    for _ in range(4):
        n = int(120 * rate)
        white = n_density * np.sqrt(rate) * rng.normal(size=(n, 3))
        walk = np.cumsum(k_walk / np.sqrt(rate) * rng.normal(size=(n, 3)), axis=0)
        segs.append(white + walk)
    taus, adev = irb.pooled_adev(segs, rate)
    assert taus[0] == pytest.approx(2 / rate) and taus[-1] == pytest.approx(15.0, rel=0.05)
    fit = irb.noise_fit(taus, adev)
    assert fit["N"] == pytest.approx(n_density, rel=0.05)
    assert fit["K"] == pytest.approx(k_walk, rel=0.35)
    assert fit["B"] < 0.3 * k_walk  # no flicker floor was drawn


def test_band_rms_of_a_tone():
    rate = 240.0
    t = np.arange(int(20 * rate)) / rate
    x = np.column_stack([0.2 * np.sin(2 * np.pi * 15.0 * t + k) for k in range(3)])
    every = np.ones(len(t), bool)
    assert irb.band_rms(x, rate, 10.0, 20.0, every) == pytest.approx(0.2 * np.sqrt(1.5), rel=0.02)
    assert irb.band_rms(x, rate, 40.0, 90.0, every) < 0.01
    assert irb.band_rms(x, rate, 5.0, 10.0, every) < 0.02


def test_linear_fit_leaves_out_an_unturned_axis():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(2000, 3)) * np.array([20.0, 30.0, 0.5])
    M = np.array([[1.01, 0.003, 0.0], [-0.002, 0.995, 0.0], [0.004, 0.001, 1.0]])
    fit, res = irb.linear_fit(truth @ M.T + 0.01 * rng.normal(size=truth.shape), truth, 5.0, False)
    assert np.isnan(fit[:, 2]).all()
    np.testing.assert_allclose(fit[:, :2], M[:, :2], atol=1e-3)
    assert res == pytest.approx(0.5 / np.sqrt(3.0), rel=0.05)  # the unturned axis is the misfit, on one axis of three


def _synthetic(scale: float, vib_rms: float) -> irb.Recording:
    """20 s still, 60 s turning about z at 0.5 Hz while moving along x, 20 s still; gyro with
    a scale error on z, the accelerometer with a 15 Hz tone in motion, both with white noise."""
    rate = 250.0
    rng = np.random.default_rng(1)
    t = np.arange(int(100 * rate)) / rate
    moving = (t >= 20.0) & (t < 80.0)
    env = np.where(moving, np.sin(np.pi * (t - 20.0) / 60.0) ** 2, 0.0)
    w_z = np.radians(40.0) * env * np.sin(2 * np.pi * 0.5 * t)
    yaw = np.cumsum(w_z) / rate
    R = so3_exp(np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw]))
    p = np.column_stack([0.1 * env * np.sin(2 * np.pi * 0.3 * t), np.zeros_like(t), np.zeros_like(t)])
    gyro = np.column_stack([np.zeros_like(t), np.zeros_like(t), scale * w_z])
    gyro += np.radians(0.01) * np.sqrt(rate) * rng.normal(size=gyro.shape) + np.radians(0.2)
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + 0.003 * np.sqrt(rate) * rng.normal(size=gyro.shape)
    tone = np.column_stack([np.sin(2 * np.pi * 15.0 * t + k) for k in range(3)]) * np.sqrt(2.0 / 3.0)
    acc += vib_rms * tone * moving[:, None]
    rest = [(1.0, 18.0), (82.0, 99.0)]
    return irb.Recording("synthetic", t, gyro, t, acc, t, R, p, rest, moving, 9.81)


def test_statistics_on_a_synthetic_recording():
    r = irb.statistics(_synthetic(scale=1.004, vib_rms=0.3))
    assert r["gyro"]["N"] == pytest.approx(0.01, rel=0.1)
    assert r["acc"]["N"] == pytest.approx(0.003, rel=0.1)
    assert abs(r["acc"]["norm_pct"]) < 0.05
    assert abs(r["bias_change"][0]["change_dps"][2]) < 0.01  # a constant bias does not change
    assert r["motion"]["acc_bands_mps2"][1] == pytest.approx(0.3, rel=0.1)  # 10-20 Hz holds the tone
    assert r["motion"]["acc_bands_mps2"][3] < 0.03
    assert r["motion"]["acc_high_mps2"] == pytest.approx(0.3 * 0.5, rel=0.25)  # a 15 Hz edge keeps about half
    scale = r["gyro_scale"]["scale_pct"]
    assert np.isnan(scale[:2]).all() and scale[2] == pytest.approx(0.4, abs=0.05)
