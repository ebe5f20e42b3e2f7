"""Smooth random fields of the instrument pose: the pose-locked systematic errors.

A field f(R, p) is a random Fourier-feature draw of a Gaussian process with unit-variance
squared-exponential kernel over orientation (correlation angle) and tip position
(correlation length), scaled to the requested SD. The same pose always gives the same value
(repeatable: 0.43 mm over repetitions of one ToF pose), different poses different ones
(3.04 mm across poses).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


class PoseField:
    """Random smooth map (R_base_tool (..., 3, 3), p_tip_base_m (..., 3)) -> (..., n_out)."""

    def __init__(
        self,
        rng: np.random.Generator,
        n_out: int,
        sd: float,
        corr_rad: float,
        corr_m: float,
        n_features: int = 96,
    ):
        if corr_rad <= 0 or corr_m <= 0:
            raise ValueError(f"correlation lengths must be positive (got {corr_rad} rad, {corr_m} m)")
        self.sd = float(sd)
        # |R1 - R2|_F ~ sqrt(2) theta for small angles: scale so that |dz| ~ theta / corr
        self._scale = np.concatenate([np.full(9, 1.0 / (np.sqrt(2.0) * corr_rad)), np.full(3, 1.0 / corr_m)])
        self._W = rng.normal(size=(n_features, 12)) * self._scale
        self._phi = rng.uniform(0.0, 2.0 * np.pi, n_features)
        a = rng.normal(size=(n_features, n_out))
        self._a = a * np.sqrt(2.0 / n_features)

    def __call__(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        R = np.asarray(R, dtype=float)
        p = np.asarray(p, dtype=float)
        z = np.concatenate([R.reshape(R.shape[:-2] + (9,)), p], -1)
        return self.sd * (np.cos(z @ self._W.T + self._phi) @ self._a)


def ou_process(rng: np.random.Generator, t_s: np.ndarray, sd: float, tau_s: float) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck samples at the (nearly uniform) times t_s (n,): SD sd,
    time constant tau_s; an AR(1) recursion at the mean sample interval."""
    n = len(t_s)
    if n == 0:
        return np.empty(0)
    dt = float(np.mean(np.diff(t_s))) if n > 1 else 1.0
    r = np.exp(-dt / tau_s)
    e = rng.normal(size=n) * sd * np.sqrt(1.0 - r * r)
    e[0] = rng.normal() * sd
    return lfilter([1.0], [1.0, -r], e)
