"""Stream latency by lock-in detection against a reference (paper, Observation Latency).

For each excitation segment at a known frequency f, the measured signal (stamped on arrival)
and the reference predicted from the robot (stamped at the event) are demodulated at f over
the same time window (Hann-weighted sinusoid fit, irregular sampling allowed), giving one complex gain
G(f) = Z_meas / Z_ref per segment. Over the frequencies, G(jw) = K e^{-jw L_d} / (1 + jw T) is
fitted by least squares (L_d and T >= 0 on the phase, then K); the low-frequency group delay
L_d + T is the stream's latency [ms], K its gain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from tiplog.calibration.fits import require


def lockin(t_ns: np.ndarray, y: np.ndarray, f_hz: float, t0_ns: int, t1_ns: int) -> complex:
    """Complex amplitude of y at f_hz over [t0, t1] (see `lockin_se`)."""
    return lockin_se(t_ns, y, f_hz, t0_ns, t1_ns)[0]


def lockin_se(t_ns: np.ndarray, y: np.ndarray, f_hz: float, t0_ns: int, t1_ns: int) -> tuple[complex, float]:
    """Complex amplitude Z of y at f_hz over [t0, t1], y ~ c + Re(Z e^{jwt}) with t in seconds
    from t0: a Hann-weighted least-squares fit of (c, cos, sin), which equals the classic
    lock-in for uniform samples and stays unbiased when frames are missing unevenly (vision
    rejects more frames while the image moves fast). Returns (Z, SE of each quadrature of Z,
    from the fit's residuals)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    yy = np.asarray(y, float)
    sel = (t_ns >= t0_ns) & (t_ns < t1_ns) & np.isfinite(yy)
    require(np.sum(sel) >= 8, "latency", f"too few samples ({int(np.sum(sel))}) in a {f_hz} Hz segment")
    t = (t_ns[sel] - t0_ns) * 1e-9
    T = (t1_ns - t0_ns) * 1e-9
    w = np.sqrt(0.5 - 0.5 * np.cos(2.0 * np.pi * t / T))
    ph = 2.0 * np.pi * f_hz * t
    X = np.stack([np.ones_like(t), np.cos(ph), np.sin(ph)], 1)
    Xw = X * w[:, None]
    c, *_ = np.linalg.lstsq(Xw, yy[sel] * w, rcond=None)
    r = yy[sel] * w - Xw @ c
    cov = np.linalg.pinv(Xw.T @ Xw) * float(r @ r) / max(len(r) - 3, 1)
    return complex(c[1] - 1j * c[2]), float(np.sqrt(0.5 * (cov[1, 1] + cov[2, 2])))


@dataclass(frozen=True)
class TransferFit:
    gain: float  # K
    dead_time_ms: float  # L_d
    time_constant_ms: float  # T
    group_delay_ms: float  # L_d + T, low-frequency group delay
    delay_se_ms: float  # its standard error from the fit's residuals
    residual: float  # RMS |G - model| over the frequencies (relative)
    freqs_hz: np.ndarray
    G: np.ndarray  # (n,) measured complex gains

    @property
    def phase_delay_ms(self) -> np.ndarray:
        """Per-frequency delay -angle(G)/w [ms]."""
        return -np.angle(self.G) / (2.0 * np.pi * self.freqs_hz) * 1e3


def model(freqs_hz: np.ndarray, K: float, L_s: float, T_s: float) -> np.ndarray:
    w = 2.0 * np.pi * np.asarray(freqs_hz, float)
    return K * np.exp(-1j * w * L_s) / (1.0 + 1j * w * T_s)


def fit_transfer(
    freqs_hz: np.ndarray, G: np.ndarray, stream: str = "stream", phase_se_rad: np.ndarray | None = None
) -> TransferFit:
    """K e^{-jw L_d} / (1 + jw T) through complex gains G at >= 3 distinct frequencies.

    L_d and T are fitted to the phase alone (unit phasors), then K to the gains: a sensor
    whose amplitude response is distorted by a pose-dependent error (the ToF's gain falls
    with the excitation's amplitude on the bench) would otherwise read as a long lag. Each
    frequency is weighted by 1 / its phase SE [rad] when given (floor 1 mrad)."""
    f = np.asarray(freqs_hz, float)
    G = np.asarray(G, complex)
    se = np.full(len(f), 1.0) if phase_se_rad is None else np.maximum(np.asarray(phase_se_rad, float), 1e-3)
    ok = np.isfinite(G) & (np.abs(G) > 0) & np.isfinite(se)
    f, G, se = f[ok], G[ok], se[ok]
    require(
        len(np.unique(f)) >= 3,
        f"latency ({stream})",
        f"needs segments at 3 or more frequencies (got {len(np.unique(f))})",
    )
    w = 2.0 * np.pi * f
    U = G / np.abs(G)
    L0 = float(np.median(-np.angle(G) / w))

    def unit(L: float, T: float) -> np.ndarray:
        return np.exp(-1j * (w * L + np.arctan(w * T)))

    def resid(x: np.ndarray) -> np.ndarray:
        r = (U - unit(x[0], x[1])) / se
        return np.concatenate([r.real, r.imag])

    lo, hi = [-1.0, 0.0], [1.0, 1.0]
    best = None
    for T0 in (0.0, max(L0, 0.0) / 2):  # two starts: pure delay, half lag
        x0 = np.clip([L0 - T0, T0], np.array(lo) + [0, 1e-9], np.array(hi) - 1e-9)
        sol = least_squares(resid, x0, bounds=(lo, hi))
        if best is None or sol.cost < best.cost:
            best = sol
    L, T = best.x
    m = model(f, 1.0, L, T)
    K = float(np.real(np.sum(G * np.conj(m))) / np.sum(np.abs(m) ** 2))
    rms = float(np.sqrt(np.mean(np.abs(G - K * m) ** 2)) / max(abs(K), 1e-12))
    J = best.jac
    dof = max(2 * len(f) - 2, 1)
    cov = np.linalg.pinv(J.T @ J) * (2.0 * best.cost / dof)
    se = float(np.sqrt(max(cov[0, 0] + cov[1, 1] + 2.0 * cov[0, 1], 0.0)) * 1e3)
    return TransferFit(K, L * 1e3, T * 1e3, (L + T) * 1e3, max(se, 1e-3), rms, f, G)
