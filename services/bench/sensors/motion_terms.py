"""Motion terms of the device models: the ToF's ranging time and beam footprint, the
accelerometer's vibration and mount compliance. Zero-sized terms draw nothing, so a clean
session's streams are what they were before these terms.

- VL53L0X: one range integrates photon returns over its ranging time (20-33 ms timing
  budgets in the data sheet's modes; at 100 Hz no more than the sample period), so a moving
  tool reports the mean range over that interval, centred on the sample instant (the
  measured 9 ms latency is the total delay). Its ~25 deg field of view makes the beam a
  footprint, not a ray: on a surface with relief about the fitted plane the range is the
  relief averaged over that footprint, which is wider the farther the surface.
- BNO085 on a clip-on module: the robot's drives and the operator's hand shake the module
  in a band above the motion (RMS growing with speed), and the clip is compliant: the IMU
  tilts against the tool under acceleration.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfilt


class SurfaceRelief:
    """A smooth random height field h(x, y) [m] over plane coordinates [m] (random Fourier
    features of a squared-exponential kernel), evaluated through a Gaussian footprint."""

    def __init__(self, rng: np.random.Generator, sd_m: float, corr_m: float, n_features: int = 128):
        self.sd = float(sd_m)
        self._W = rng.normal(size=(n_features, 2)) / corr_m
        self._phi = rng.uniform(0.0, 2.0 * np.pi, n_features)
        self._a = rng.normal(size=n_features) * np.sqrt(2.0 / n_features)

    def __call__(self, xy_m: np.ndarray, footprint_sd_m: np.ndarray) -> np.ndarray:
        """Relief at xy (n, 2) averaged over Gaussian footprints of SD footprint_sd_m (n,)."""
        k2 = (self._W**2).sum(1)
        atten = np.exp(-0.5 * footprint_sd_m[:, None] ** 2 * k2[None, :])
        return self.sd * ((np.cos(xy_m @ self._W.T + self._phi) * atten) @ self._a)


def plane_axes(m: np.ndarray) -> np.ndarray:
    """Two unit vectors spanning the plane with normal m, as rows (2, 3)."""
    e1 = np.cross(m, [1.0, 0.0, 0.0] if abs(m[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(m, e1)])


def integration_offsets_ns(integration_ms: float, n_sub: int = 5) -> np.ndarray:
    """Sub-sample offsets [ns] spanning the ranging time, centred on zero."""
    if integration_ms <= 0:
        return np.zeros(1, dtype=np.int64)
    return np.round(np.linspace(-0.5, 0.5, n_sub) * integration_ms * 1e6).astype(np.int64)


def session_corr(rng: np.random.Generator | None, corr: float, spread: float) -> float:
    """A correlation length drawn log-uniform in [corr / spread, corr * spread] (corr itself
    when spread is 1 or no generator is given)."""
    if rng is None or spread <= 1.0:
        return corr
    return float(corr * np.exp(rng.uniform(-np.log(spread), np.log(spread))))


def vibration(
    rng: np.random.Generator, t_s: np.ndarray, rms_mps2: np.ndarray, centre_hz: float, rate_hz: float
) -> np.ndarray:
    """Band-limited vibration (n, 3) [m/s^2]: white noise through an octave band-pass around
    centre_hz, normalised to unit RMS, times the per-sample RMS."""
    n = len(t_s)
    lo, hi = centre_hz / np.sqrt(2.0), min(centre_hz * np.sqrt(2.0), 0.45 * rate_hz)
    if n < 16 or lo >= hi:
        return np.zeros((n, 3))
    sos = butter(2, [lo, hi], btype="bandpass", fs=rate_hz, output="sos")
    x = sosfilt(sos, rng.normal(size=(n + 256, 3)), axis=0)[256:]
    x /= max(float(np.sqrt(np.mean(x**2))), 1e-12)
    return x * rms_mps2[:, None]


def compliance_tilt(a_dyn_imu: np.ndarray, shaft_imu: np.ndarray, deg_per_mps2: float) -> np.ndarray:
    """Rotation vectors (n, 3) [rad] of the IMU against the tool: the clip bends away from the
    acceleration's part across the shaft, deg_per_mps2 per m/s^2."""
    return np.radians(deg_per_mps2) * np.cross(a_dyn_imu, shaft_imu)
