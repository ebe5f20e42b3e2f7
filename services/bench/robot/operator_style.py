"""How the teleoperating operator moves beyond the intended path: tremor, hesitation pauses and
detours (pure numpy). The default operator is none of these, and leaves the teleop motion as
drawn; the style is applied to a block's accepted draw, so two scenarios that differ only in
operator fields share the same intended motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

TREMOR_BAND_HZ = 1.5  # half-width of the tremor's band about its frequency
PAUSE_RAMP_S = 0.4  # the slowing into and out of a pause
DETOUR_BAND_HZ = (0.3, 0.8)  # detours: wandering slower than tremor, faster than the intended path


@dataclass(frozen=True)
class OperatorStyle:
    """tremor_mm: RMS tip displacement of the tremor per tilt axis [mm] at tremor_hz;
    pauses_per_min: hesitation pauses (the hand stops on the path) of pause_s each;
    detour: extra wandering of the tilt, as a fraction of the intended tilt's RMS (path economy)."""

    tremor_mm: float = 0.0
    tremor_hz: float = 9.0
    pauses_per_min: float = 0.0
    pause_s: float = 1.5
    detour: float = 0.0

    @property
    def active(self) -> bool:
        return self.tremor_mm > 0.0 or self.pauses_per_min > 0.0 or self.detour > 0.0


def _band(rng: np.random.Generator, n: int, rate_hz: float, lo_hz: float, hi_hz: float) -> np.ndarray:
    """Band-limited Gaussian noise (n,), zero mean, unit SD."""
    sos = butter(2, (max(lo_hz, 0.01), hi_hz), btype="band", fs=rate_hz, output="sos")
    y = sosfiltfilt(sos, rng.standard_normal(n + 4000))[2000:-2000]
    return (y - y.mean()) / y.std()


def hesitation_clock(rng: np.random.Generator, n: int, rate_hz: float, count: int, pause_s: float, margin: int):
    """Sample times (n,) [samples] at which to read the intended path: the operator stops `count`
    times for pause_s (smooth slowing in and out) at random places more than `margin` samples from
    either end, and moves correspondingly faster elsewhere, so the block still ends where intended."""
    rate = np.ones(n)
    if count <= 0:
        return np.arange(n, dtype=float)
    hold = int(round(pause_s * rate_hz))
    ramp = int(round(PAUSE_RAMP_S * rate_hz))
    width = hold + 2 * ramp
    span = n - 2 * margin - width
    if span <= width * count:
        raise ValueError("operator: too many or too long pauses for the block")
    starts = np.sort(rng.choice(span // width, size=count, replace=False)) * width + margin
    dip = np.concatenate([0.5 + 0.5 * np.cos(np.linspace(0, np.pi, ramp)), np.zeros(hold),
                          0.5 - 0.5 * np.cos(np.linspace(0, np.pi, ramp))])  # fmt: skip
    for s in starts:
        rate[s : s + width] = np.minimum(rate[s : s + width], dip)
    clock = np.concatenate([[0.0], np.cumsum(rate[:-1])])
    return clock * (n - 1) / clock[-1]


def apply(
    poses: np.ndarray, style: OperatorStyle, rng: np.random.Generator, rate_hz: float, envelope: np.ndarray
) -> np.ndarray:
    """The intended (pitch, yaw, depth, roll) poses (n, 4) as this operator moves them; `envelope`
    (n,) in [0, 1] fades tremor and detours in and out with the block."""
    if not style.active:
        return poses
    n = len(poses)
    out = poses.copy()
    if style.detour > 0.0:
        lo, hi = DETOUR_BAND_HZ
        for j in (0, 1):
            out[:, j] += style.detour * np.std(poses[:, j]) * _band(rng, n, rate_hz, lo, hi) * envelope
    if style.pauses_per_min > 0.0:
        count = int(round(style.pauses_per_min * n / rate_hz / 60.0))
        margin = int(np.argmax(envelope >= 1.0))
        clock = hesitation_clock(rng, n, rate_hz, count, style.pause_s, margin)
        idx = np.arange(n, dtype=float)
        out = np.stack([np.interp(clock, idx, out[:, j]) for j in range(4)], 1)
    if style.tremor_mm > 0.0:
        f = style.tremor_hz
        for j in (0, 1):
            amp_rad = style.tremor_mm * 1e-3 / out[:, 2]
            out[:, j] += amp_rad * _band(rng, n, rate_hz, f - TREMOR_BAND_HZ, f + TREMOR_BAND_HZ) * envelope
    return out
