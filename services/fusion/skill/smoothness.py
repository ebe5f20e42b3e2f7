"""Smoothness of a speed profile: spectral arc length (SPARC) and log dimensionless jerk (LDLJ).

Both as Balasubramanian et al. define them ("A robust and sensitive metric for quantifying
movement smoothness", IEEE TBME 2012; "On the analysis of movement smoothness", JNER 2015), on a
speed profile sampled at a uniform rate. Values are negative; closer to zero is smoother. For the
reference profile, a Gaussian speed exp(-5 t^2) on t = -1, -0.99, ..., 0.99 s at 100 Hz, SPARC is
-1.41403 and LDLJ -5.81636 (the published implementation's documented values).
"""

from __future__ import annotations

import numpy as np

SPARC_CUTOFF_HZ = 10.0  # published default: no arc length beyond this frequency
SPARC_AMPLITUDE_THRESHOLD = 0.05  # published default: spectrum kept while above 5 % of its peak
SPARC_PAD_LEVEL = 4  # published default: FFT length 2^(ceil(log2 n) + 4)


def sparc(
    speed: np.ndarray,
    rate_hz: float,
    pad_level: int = SPARC_PAD_LEVEL,
    cutoff_hz: float = SPARC_CUTOFF_HZ,
    amplitude_threshold: float = SPARC_AMPLITUDE_THRESHOLD,
) -> float:
    """Spectral arc length of a speed profile (n,) [any unit] sampled at rate_hz (dimensionless).

    The arc length of the peak-normalised magnitude spectrum, frequency axis normalised to the
    band used, over 0..cutoff_hz trimmed to the first and last bins at or above the amplitude
    threshold."""
    v = np.asarray(speed, dtype=float)
    if v.ndim != 1 or len(v) < 2:
        raise ValueError("sparc: need a 1-D speed profile of at least two samples")
    if not np.all(np.isfinite(v)) or not np.any(v != 0.0):
        raise ValueError("sparc: the speed profile is all zero or not finite")
    nfft = int(2 ** (np.ceil(np.log2(len(v))) + pad_level))
    f_hz = np.arange(nfft) * (rate_hz / nfft)
    mag = np.abs(np.fft.fft(v, nfft))
    mag = mag / mag.max()
    band = f_hz <= cutoff_hz
    f_sel, m_sel = f_hz[band], mag[band]
    above = np.nonzero(m_sel >= amplitude_threshold)[0]
    f_sel, m_sel = f_sel[above[0] : above[-1] + 1], m_sel[above[0] : above[-1] + 1]
    if len(f_sel) < 2:
        return 0.0
    df = np.diff(f_sel) / (f_sel[-1] - f_sel[0])
    return float(-np.sum(np.sqrt(df**2 + np.diff(m_sel) ** 2)))


def dimensionless_jerk(speed: np.ndarray, rate_hz: float) -> float:
    """Dimensionless jerk of a speed profile (n,): -(T^3 / v_peak^2) * integral of (d^2 v / dt^2)^2,
    T = n / rate_hz, the second derivative by second differences."""
    v = np.asarray(speed, dtype=float)
    if v.ndim != 1 or len(v) < 3:
        raise ValueError("dimensionless jerk: need a 1-D speed profile of at least three samples")
    peak = np.max(np.abs(v))
    if not np.isfinite(peak) or peak == 0.0:
        raise ValueError("dimensionless jerk: the speed profile is all zero or not finite")
    dt = 1.0 / rate_hz
    jerk = np.diff(v, 2) / dt**2
    duration = len(v) * dt
    return float(-(duration**3 / peak**2) * np.sum(jerk**2) * dt)


def ldlj(speed: np.ndarray, rate_hz: float) -> float:
    """Log dimensionless jerk of a speed profile (n,) sampled at rate_hz: -ln |dimensionless jerk|."""
    dj = dimensionless_jerk(speed, rate_hz)
    if dj == 0.0:
        raise ValueError("log dimensionless jerk: the speed profile has no jerk at all (constant speed)")
    return float(-np.log(abs(dj)))
