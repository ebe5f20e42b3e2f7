"""Latency by lock-in: the pure fit on synthetic delayed sinusoids. The paper's latency table on
a bench latency-protocol session against the bench's true latencies is an accuracy check
(benchmarks/accuracy_checks/test_calibrate_latency.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tiplog.calibration.fits import DegenerateDataError
from tiplog.calibration.fits.latency import fit_transfer, lockin, model


def _segment(rng, f, delay_s, tau_s, rate_hz=100.0, drop=0.3):
    """Irregularly sampled, gappy response of a first-order lag + delay to a sine."""
    T = max(6.0 / f, 10.0)
    t = np.sort(rng.uniform(0, T, int(T * rate_hz)))
    keep = rng.random(len(t)) > drop * (np.abs(np.cos(2 * np.pi * f * t)) > 0.7)  # drops at high speed
    t = t[keep]
    g = model(np.array([f]), 1.0, delay_s, tau_s)[0]
    y = 2.0 + np.abs(g) * np.sin(2 * np.pi * f * t + np.angle(g)) + rng.normal(size=len(t)) * 0.01
    ref_t = np.arange(0, T, 0.005)
    return (t * 1e9).astype(np.int64), y, (ref_t * 1e9).astype(np.int64), np.sin(2 * np.pi * f * ref_t), int(T * 1e9)


def test_lockin_fit_recovers_delay_and_lag_from_gappy_irregular_samples():
    rng = np.random.default_rng(0)
    freqs = np.array([0.15, 0.2, 0.3, 0.5, 0.8, 1.0, 1.3, 1.6])
    G = []
    for f in freqs:
        tm, y, tr, yr, T = _segment(rng, f, 0.009, 0.004)
        G.append(lockin(tm, y, f, 0, T) / lockin(tr, yr, f, 0, T))
    fit = fit_transfer(freqs, np.array(G))
    assert abs(fit.group_delay_ms - 13.0) < 0.5
    assert abs(fit.gain - 1.0) < 0.02


def test_fit_refuses_fewer_than_three_frequencies():
    with pytest.raises(DegenerateDataError, match="3 or more frequencies"):
        fit_transfer(np.array([0.5, 0.5, 1.0]), np.ones(3, complex))
