"""Skill-assessment metrics of one segment of a tip trajectory, with intervals from the estimate's
own uncertainty (pure numpy: no bus, no files).

A `Motion` is a trajectory on a uniform grid (`resample`): tip positions, cumulative roll, the
RCM and, for an estimate, its 1-sigma per axis. `segment_metrics` computes every figure of
`METRICS` from it with `MetricsParams`' filtering and thresholds; `draw_intervals` repeats that on
trajectories drawn about the estimate from its sigmas, correlated in time (see `correlated_noise`),
and returns each metric's interval.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import gaussian_filter1d

from services.fusion.skill import kinematics as kin
from services.fusion.skill.smoothness import ldlj, sparc

# key -> (unit, what): the order of the table and the JSON
METRICS: dict[str, tuple[str, str]] = {
    "duration_s": ("s", "duration"),
    "path_length_mm": ("mm", "tip path length"),
    "depth_path_mm": ("mm", "depth perception: path of the insertion depth"),
    "angular_path_deg": ("deg", "angle swept by the shaft about the RCM"),
    "elevation_path_deg": ("deg", "path of the shaft's angle from vertical"),
    "azimuth_path_deg": ("deg", "path of the shaft's azimuth about the vertical"),
    "roll_path_deg": ("deg", "path of the roll about the shaft"),
    "economy_straight": ("", "straight start-end distance / path length"),
    "economy_fulcrum": ("", "pivot-and-insert start-end path / path length"),
    "movement_economy_straight": ("", "straight-line economy, mean over movements"),
    "movement_economy_fulcrum": ("", "fulcrum-aware economy, mean over movements"),
    "working_volume_cm3": ("cm3", "convex hull of the tip"),
    "idle_time_s": ("s", "time with the tip speed under the idle threshold"),
    "movements": ("", "movements in the speed profile"),
    "mean_speed_mmps": ("mm/s", "mean tip speed"),
    "peak_speed_mmps": ("mm/s", "peak tip speed"),
    "ldlj": ("", "log dimensionless jerk of the tip speed"),
    "sparc": ("", "spectral arc length of the tip speed"),
}


@dataclass(frozen=True)
class MetricsParams:
    """Grid, filtering and thresholds of the metrics, and how intervals are drawn."""

    rate_hz: float = 100.0  # uniform grid every trajectory is resampled to (SPARC's reference rate)
    path_cutoff_hz: float = 2.0  # low-pass before paths, angles, volume and economy
    speed_cutoff_hz: float = 2.0  # low-pass of the tip before its speed (speeds, idle, movements, LDLJ, SPARC)
    idle_speed_mmps: float = 5.0  # idle: tip speed under this
    movement_speed_mmps: float = 5.0  # a movement: tip speed at or above this ...
    movement_min_s: float = 0.3  # ... for at least this long ...
    movement_merge_s: float = 0.2  # ... runs closer than this joined into one
    min_segment_s: float = 2.0  # shorter segments are refused: the filters and SPARC need this much
    draws: int = 200  # trajectories drawn from the estimate's uncertainty per segment
    error_corner_hz: float = 0.4  # corner of the drawn errors' spectrum (see `correlated_noise`)
    envelope_s: float = 1.0  # the stream's sigma smoothed over this (see `sigma_envelope`)
    sigma_scale: float = 0.33  # drawn errors' SD across the shaft over the stream's smoothed sigma
    depth_sigma_scale: float = 0.27  # ... and along the shaft (the insertion depth's error)
    depth_scale_sd: float = 0.033  # relative error of the estimate's depth excursions (1 sigma), per draw
    roll_scale_sd: float = 0.002  # the gyro's scale-factor error about the shaft (1 sigma), per draw
    level: float = 0.95  # interval level

    def __post_init__(self) -> None:
        if not 0.0 < self.path_cutoff_hz < self.rate_hz / 2 or not 0.0 < self.speed_cutoff_hz < self.rate_hz / 2:
            raise ValueError("metrics: the cut-off frequencies must lie between 0 and half the grid rate")
        if (
            self.draws < 0
            or not 0.0 < self.level < 1.0
            or min(self.error_corner_hz, self.envelope_s, self.sigma_scale, self.depth_sigma_scale) <= 0
            or min(self.depth_scale_sd, self.roll_scale_sd) < 0
        ):
            raise ValueError(
                "metrics: draws >= 0, 0 < level < 1, error_corner_hz, envelope_s, sigma_scale and "
                "depth_sigma_scale > 0, and depth_scale_sd and roll_scale_sd >= 0 are required"
            )


@dataclass(frozen=True)
class Motion:
    """A trajectory on a uniform grid: t_s (n,), p_tip_base_m (n, 3), roll_rad (n,) cumulative roll
    about the shaft, rcm_base_m (3,); for an estimate tip_sigma_m (n, 3) and roll_sigma_rad (n,)."""

    t_s: np.ndarray
    p_tip_base_m: np.ndarray
    roll_rad: np.ndarray
    rcm_base_m: np.ndarray
    tip_sigma_m: np.ndarray | None = None
    roll_sigma_rad: np.ndarray | None = None

    def window(self, t0_s: float, t1_s: float) -> Motion:
        """The samples with t0_s <= t < t1_s."""
        sel = (self.t_s >= t0_s) & (self.t_s < t1_s)

        def cut(x):
            return None if x is None else x[sel]

        return Motion(
            self.t_s[sel], self.p_tip_base_m[sel], self.roll_rad[sel], self.rcm_base_m,
            cut(self.tip_sigma_m), cut(self.roll_sigma_rad),
        )  # fmt: skip


def resample(
    t_ns: np.ndarray,
    p_tip_base_m: np.ndarray,
    roll_rad: np.ndarray,
    rcm_base_m: np.ndarray,
    rate_hz: float,
    tip_sigma_m: np.ndarray | None = None,
    roll_sigma_rad: np.ndarray | None = None,
    t0_ns: int | None = None,
) -> Motion:
    """A `Motion` on the grid t0 + k / rate_hz inside the samples' span, by linear interpolation
    (stamps int64 ns, sorted; t0 defaults to the first stamp: give a shared t0 to put two
    trajectories on one grid)."""
    t_ns = np.asarray(t_ns, np.int64)
    t0 = int(t_ns[0]) if t0_ns is None else int(t0_ns)
    k0 = int(np.ceil((t_ns[0] - t0) * 1e-9 * rate_hz - 1e-9))
    k1 = int(np.floor((t_ns[-1] - t0) * 1e-9 * rate_hz + 1e-9))
    t_s = np.arange(k0, k1 + 1) / rate_hz
    ts = (t_ns - t0) * 1e-9

    def interp(y):
        if y is None:
            return None
        y = np.asarray(y, dtype=float)
        if y.ndim == 1:
            return np.interp(t_s, ts, y)
        return np.stack([np.interp(t_s, ts, y[:, j]) for j in range(y.shape[1])], 1)

    return Motion(
        t_s, interp(p_tip_base_m), interp(roll_rad), np.asarray(rcm_base_m, float),
        interp(tip_sigma_m), interp(roll_sigma_rad),
    )  # fmt: skip


def segment_metrics(m: Motion, params: MetricsParams) -> dict[str, float]:
    """Every metric of `METRICS` for one segment (see the module docstring and docs/metrics.md)."""
    n, rate = len(m.t_s), params.rate_hz
    if n / rate < params.min_segment_s:
        raise ValueError(
            f"the trajectory covers {n / rate:.2f} s; the metrics need at least {params.min_segment_s:g} s"
        )
    p = kin.lowpass(m.p_tip_base_m, rate, params.path_cutoff_hz)
    p_v = kin.lowpass(m.p_tip_base_m, rate, params.speed_cutoff_hz)
    roll = kin.lowpass(m.roll_rad, rate, params.path_cutoff_hz)
    depth, u = kin.shaft_coordinates(p, m.rcm_base_m)
    elevation, azimuth = kin.elevation_azimuth(u)
    v = kin.speed(p_v, rate)
    moves = kin.movements(v, rate, params.movement_speed_mmps * 1e-3, params.movement_min_s, params.movement_merge_s)
    econ = np.array([kin.economy(p[a:b], m.rcm_base_m) for a, b in moves]).reshape(-1, 2)
    straight, fulcrum = kin.economy(p, m.rcm_base_m)
    return {
        "duration_s": n / rate,
        "path_length_mm": kin.path_length(p) * 1e3,
        "depth_path_mm": kin.path_length(depth) * 1e3,
        "angular_path_deg": float(np.rad2deg(kin.swept_angle(u))),
        "elevation_path_deg": float(np.rad2deg(kin.path_length(elevation))),
        "azimuth_path_deg": float(np.rad2deg(kin.path_length(azimuth))),
        "roll_path_deg": float(np.rad2deg(kin.path_length(roll))),
        "economy_straight": straight,
        "economy_fulcrum": fulcrum,
        "movement_economy_straight": float(np.nanmean(econ[:, 0])) if len(econ) else float("nan"),
        "movement_economy_fulcrum": float(np.nanmean(econ[:, 1])) if len(econ) else float("nan"),
        "working_volume_cm3": kin.working_volume(p) * 1e6,
        "idle_time_s": kin.idle_time(v, rate, params.idle_speed_mmps * 1e-3),
        "movements": float(len(moves)),
        "mean_speed_mmps": float(np.mean(v)) * 1e3,
        "peak_speed_mmps": float(np.max(v)) * 1e3,
        "ldlj": ldlj(v, rate),
        "sparc": sparc(v, rate),
    }


# metrics whose interval takes off what the estimate's own error added to them (see `draw_intervals`)
DEBIASED = ("depth_path_mm",)


def correlated_noise(rng: np.random.Generator, n: int, dims: int, rate_hz: float, corner_hz: float) -> np.ndarray:
    """Stationary Gaussian noise (n, dims), unit variance per column, of a second-order Gauss-Markov
    process: power spectrum proportional to 1 / (1 + (f / corner_hz)^2)^2 (two first-order lags in
    series; autocorrelation (1 + |lag| / T) exp(-|lag| / T), T = 1 / (2 pi corner_hz)). Made by
    shaping white noise in the frequency domain over n samples plus ten time constants of padding,
    so the start and end of the result are uncorrelated as in a stationary process."""
    pad = int(np.ceil(10.0 * rate_hz / (2.0 * np.pi * corner_hz)))
    m = n + pad
    f = np.fft.rfftfreq(m, 1.0 / rate_hz)
    gain = 1.0 / (1.0 + (f / corner_hz) ** 2)  # amplitude: the square root of the spectrum
    # the variance of the shaped (circular) noise: (1/m) sum over all m bins of gain^2
    full = np.concatenate([gain, gain[1 : (m + 1) // 2][::-1]])
    gain = gain / np.sqrt(np.sum(full**2) / m)
    white = rng.standard_normal((m, dims))
    return np.fft.irfft(np.fft.rfft(white, axis=0) * gain[:, None], n=m, axis=0)[:n]


def sigma_envelope(sigma: np.ndarray, rate_hz: float, envelope_s: float) -> np.ndarray:
    """The stream's sigmas (n,) or (n, k) smoothed in time: the square root of sigma^2 averaged with a
    Gaussian window of SD envelope_s. A filter's sigma rises between measurements and drops at each
    one; multiplying the drawn noise by it unsmoothed would put that sawtooth's frequencies into the
    drawn errors (and into the jerk), which the estimate's own errors do not have."""
    return np.sqrt(gaussian_filter1d(np.asarray(sigma, dtype=float) ** 2, envelope_s * rate_hz, axis=0, mode="nearest"))


def drawn_motion(m: Motion, rng: np.random.Generator, params: MetricsParams) -> Motion:
    """One trajectory drawn about the estimate (base frame, m and rad).

    The tip is offset by `sigma_envelope` times `correlated_noise` per base axis (axes drawn
    independently: the estimate carries no cross-covariance), that offset's component along the
    shaft scaled by `params.depth_sigma_scale` and the rest by `params.sigma_scale` (the estimate's
    error lies mostly along the shaft, where the depth comes from the ToF, less across it, where
    vision fixes the direction). Then the errors the sigmas do not carry, one draw per trajectory:
    the depth's excursions about the segment's mean depth scaled by 1 + `depth_scale_sd` x N(0, 1)
    (the depth's geometry as calibrated), the roll's about its start by 1 + `roll_scale_sd` x
    N(0, 1) (the gyro's scale factor: roll about the shaft is the gyro's alone, a shaft's
    silhouette does not show it). The roll is offset by `sigma_scale` times its envelope times noise."""
    n, rate = len(m.t_s), params.rate_hz
    z = correlated_noise(rng, n, 4, rate, params.error_corner_hz)
    scale_depth, scale_roll = 1.0 + np.array([params.depth_scale_sd, params.roll_scale_sd]) * rng.standard_normal(2)
    p, roll = m.p_tip_base_m, m.roll_rad
    if m.tip_sigma_m is not None:
        depth, u = kin.shaft_coordinates(p, m.rcm_base_m)
        d = sigma_envelope(m.tip_sigma_m, rate, params.envelope_s) * z[:, :3]
        along = np.einsum("ij,ij->i", d, u)
        d = params.sigma_scale * (d - along[:, None] * u)
        depth = depth.mean() + (depth - depth.mean()) * scale_depth + params.depth_sigma_scale * along
        p = m.rcm_base_m + depth[:, None] * u + d
    roll = roll[0] + (roll - roll[0]) * scale_roll
    if m.roll_sigma_rad is not None:
        roll = roll + params.sigma_scale * sigma_envelope(m.roll_sigma_rad, rate, params.envelope_s) * z[:, 3]
    return replace(m, p_tip_base_m=p, roll_rad=roll)


def draw_intervals(
    m: Motion, point: dict[str, float], params: MetricsParams, seed: int = 0
) -> dict[str, tuple[float, float]]:
    """{metric: (low, high)}: the spread of the metric over `params.draws` trajectories drawn about
    the estimate, centred on the estimate's value: with q_lo, q_mid, q_hi the draws' lower, middle
    and upper quantiles and x the estimate's value, (x - q_mid + q_lo, x - q_mid + q_hi); for the
    metrics of `DEBIASED`, placed about x less the draws' mean lengthening of the path (mean - x).

    For most metrics the draws give the spread, not a bias correction: drawn errors add to the
    estimate's own, so the draws' shift from x (a longer path, a lower LDLJ) is what a second
    error adds, and the estimate's actual shift from the truth depends on how its error lies along
    the motion, which the stream's per-axis sigma does not carry (on the bench the draws' shift was
    several times the estimate's own for LDLJ, the tip path and the mean speed; docs/metrics.md).
    The depth path is the exception: its error is drawn at its own size along the shaft, and what
    it adds to the path is one-sided and larger than its spread (the depth moves slowly beside its
    noise). Where the depth moves, a noise's velocity adds to the depth speed in quadrature, so the
    path added grows with the noise's variance and a second error of the estimate's size adds what
    the first did: the draws' lengthening is taken off. Where the tip is wholly still, the path
    grows with the noise's SD and the first error added up to 2.4 times (1 / (sqrt 2 - 1)) what
    the second does: there it is taken off in part. Empty without draws or sigmas."""
    if params.draws == 0 or m.tip_sigma_m is None:
        return {}
    rng = np.random.default_rng(seed)
    rows = [segment_metrics(drawn_motion(m, rng, params), params) for _ in range(params.draws)]
    out = {}
    a = (1.0 - params.level) / 2.0
    for key in METRICS:
        vals = np.array([r[key] for r in rows], dtype=float)
        vals = vals[np.isfinite(vals)]
        x = point.get(key, float("nan"))
        if key == "duration_s" or len(vals) == 0 or not np.isfinite(x):
            continue
        q_lo, q_mid, q_hi = np.quantile(vals, [a, 0.5, 1.0 - a])
        centre = x - max(float(np.mean(vals)) - x, 0.0) if key in DEBIASED else x
        out[key] = (float(centre - q_mid + q_lo), float(centre - q_mid + q_hi))
    return out
