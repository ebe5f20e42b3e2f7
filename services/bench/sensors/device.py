"""Sensor models of the clip-on module, vectorised over a whole session.

Input: the robot's ground truth at 1 kHz (`GroundTruth`: t_ns, R_base_tool, p_tip_base_m)
and the true bench constants. Output: one `Stream` per sensor with the true sample time,
the device clock stamp, the host arrival stamp (sample time + latency + jitter), the values
and the status. Kinematics come from finite differences on the 1 kHz truth, smoothed with a
Savitzky-Golay filter: body rate from relative rotations, the IMU's specific force at its
own position (lever arm) as R_base_imu^T (d2/dt2 p_imu - g), g = (0, 0, -9.80665) m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import savgol_filter

from services.bench.scenario import ClockConfig, Scenario
from services.bench.sensors import motion_terms as mt
from services.bench.sensors.calibration import BenchConstants
from services.bench.sensors.pose_field import PoseField, ou_process
from tiplog.geometry import so3_exp, so3_log
from tiplog.v1.device_pb2 import TofStatus

G_BASE = np.array([0.0, 0.0, -9.80665])


@dataclass
class Stream:
    """One sensor stream: per sample true time, device stamp and host arrival [ns]."""

    name: str
    t_true_ns: np.ndarray
    device_ns: np.ndarray
    arrival_ns: np.ndarray
    values: np.ndarray
    status: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_true_ns)


@dataclass
class Kinematics:
    """Truth-derived kinematics at the 1 kHz grid: body rate (tool frame) [rad/s], IMU
    specific force (IMU frame) [m/s^2], plus the poses."""

    t_ns: np.ndarray
    R_base_tool: np.ndarray
    p_tip_base_m: np.ndarray
    omega_tool_radps: np.ndarray
    f_imu_mps2: np.ndarray
    R_base_imu: np.ndarray


def _savgol_window(n: int, want: int) -> int:
    w = min(want, n if n % 2 else n - 1)
    return max(w, 5) if n >= 5 else 0


def kinematics(gt: Any, const: BenchConstants, smooth_ms: float = 15.0) -> Kinematics:
    """Angular velocity and the IMU's specific force from the 1 kHz truth (lever arm included)."""
    t = np.asarray(gt.t_ns, dtype=np.int64)
    R = np.asarray(gt.R_base_tool, dtype=float)
    p = np.asarray(gt.p_tip_base_m, dtype=float)
    n = len(t)
    dt = float(np.median(np.diff(t))) * 1e-9 if n > 1 else 1e-3
    omega = np.zeros((n, 3))
    if n > 2:
        rel = np.einsum("nji,njk->nik", R[:-2], R[2:])  # R_{k-1}^T R_{k+1}
        omega[1:-1] = so3_log(rel) / (2.0 * dt)
        omega[0], omega[-1] = omega[1], omega[-2]
    w_rate = _savgol_window(n, int(round(smooth_ms * 1e-3 / dt)) | 1)
    if w_rate:
        omega = savgol_filter(omega, w_rate, 2, axis=0)
    p_imu = p + np.einsum("nij,j->ni", R, const.p_imu_tool_m)
    w_acc = _savgol_window(n, int(round(2 * smooth_ms * 1e-3 / dt)) | 1)
    if w_acc:
        a = savgol_filter(p_imu, w_acc, 3, deriv=2, delta=dt, axis=0)
    else:
        a = np.zeros_like(p_imu)
    R_base_imu = R @ const.R_tool_imu
    f = np.einsum("nji,nj->ni", R_base_imu, a - G_BASE)
    return Kinematics(t, R, p, omega, f, R_base_imu)


def _interp(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    tq = np.asarray(tq, dtype=float)
    t = np.asarray(t, dtype=float)
    if y.ndim == 1:
        return np.interp(tq, t, y)
    flat = y.reshape(len(t), -1)
    out = np.stack([np.interp(tq, t, flat[:, j]) for j in range(flat.shape[1])], -1)
    return out.reshape((len(tq),) + y.shape[1:])


def _interp_R(tq: np.ndarray, t: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation at query times: nearest-below sample times the relative rotation's fraction."""
    tq = np.asarray(tq, dtype=float)
    t = np.asarray(t, dtype=float)
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    a = np.clip((tq - t[i]) / (t[i + 1] - t[i]), 0.0, 1.0)
    rel = so3_log(np.einsum("nji,njk->nik", R[i], R[i + 1]))
    return R[i] @ so3_exp(a[:, None] * rel)


@dataclass
class DeviceClock:
    """The module's clock: offset and drift against the host clock; samples tick on it."""

    offset_ns: int
    drift: float  # device seconds per host second - 1
    jitter_ns: float

    @classmethod
    def draw(cls, cfg: ClockConfig, rng: np.random.Generator) -> DeviceClock:
        return cls(
            int(rng.uniform(0, cfg.offset_s_max) * 1e9),
            cfg.drift_ppm_sd * 1e-6 * rng.normal(),
            cfg.sample_jitter_us * 1e3,
        )

    def sample_times(self, rate_hz: float, t_end_ns: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(true sample times [ns, host clock], device stamps [ns]) of a stream at rate_hz."""
        period = 1e9 / rate_hz
        n = int((t_end_ns - 1e6) / period * (1 + self.drift))
        k = np.arange(max(n, 0))
        dev = self.offset_ns + np.round(rng.uniform(0, period) + k * period).astype(np.int64)
        t = (dev - self.offset_ns) / (1.0 + self.drift) + rng.normal(size=len(k)) * self.jitter_ns
        t = np.clip(t, 0, t_end_ns - 1)
        return np.maximum.accumulate(np.round(t)).astype(np.int64), dev


def arrival(t_ns: np.ndarray, latency_ms: float, jitter_ms: float, rng: np.random.Generator) -> np.ndarray:
    """Host arrival stamps: sample time + latency + jitter (clipped to 3 SD), in order."""
    j = np.clip(rng.normal(size=len(t_ns)), -3, 3) * jitter_ms
    a = t_ns + np.round((latency_ms + j) * 1e6).astype(np.int64)
    k = np.arange(len(a))
    return np.maximum.accumulate(a - k) + k  # strictly increasing: one USB frame after another


def gyro(kin: Kinematics, sc: Scenario, const: BenchConstants, clock: DeviceClock, rng: np.random.Generator) -> Stream:
    c = sc.gyro
    t, dev = clock.sample_times(c.rate_hz, int(kin.t_ns[-1]), rng)
    w_imu = _interp(t, kin.t_ns, kin.omega_tool_radps) @ const.R_tool_imu  # R_tool_imu^T w
    dt = 1.0 / c.rate_hz
    q = np.radians(c.bias_rw_static_dps_rts + c.bias_rw_motion_dps_rts_per_radps * np.linalg.norm(w_imu, axis=1))
    steps = rng.normal(size=w_imu.shape) * (q * np.sqrt(dt))[:, None]
    bias = np.radians(c.bias_instability_dps) * rng.normal(size=3) + np.cumsum(steps, 0)
    scale = 1.0 + c.scale_sd * rng.normal(size=3)
    noise = np.radians(c.noise_density_dps_rthz) * np.sqrt(c.rate_hz) * rng.normal(size=w_imu.shape)
    vals = w_imu * scale + bias + noise
    arr = arrival(t, c.latency_ms, c.latency_jitter_ms, rng)
    return Stream("gyro", t, dev, arr, vals, extra={"bias_radps": bias})


def _pose_at(kin: Kinematics, t: np.ndarray, decim: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid (every `decim`-th truth sample) and the poses there, for evaluating pose fields."""
    idx = np.arange(0, len(kin.t_ns), decim)
    if idx[-1] != len(kin.t_ns) - 1:
        idx = np.append(idx, len(kin.t_ns) - 1)
    return kin.t_ns[idx], kin.R_base_tool[idx], kin.p_tip_base_m[idx]


def pose_field_at(fld: PoseField, kin: Kinematics, t: np.ndarray) -> np.ndarray:
    tg, Rg, pg = _pose_at(kin, t)
    return _interp(t, tg, fld(Rg, pg))


def accel(kin: Kinematics, sc: Scenario, const: BenchConstants, clock: DeviceClock, rng: np.random.Generator) -> Stream:
    c = sc.accel
    t, dev = clock.sample_times(c.rate_hz, int(kin.t_ns[-1]), rng)
    f = _interp(t, kin.t_ns, kin.f_imu_mps2)
    tilt = PoseField(rng, 3, np.radians(c.pose_tilt_sd_deg) / np.sqrt(2.0), np.radians(c.pose_corr_deg), c.pose_corr_m)
    spread = PoseField(rng, 1, c.noise_pose_spread, np.radians(c.pose_corr_deg), c.pose_corr_m)
    f = np.einsum("nij,nj->ni", so3_exp(pose_field_at(tilt, kin, t)), f)
    norm_gain = np.ones(len(t))
    if c.self_recal:
        ts = t * 1e-9
        after = ts >= c.self_recal_jump_time_s
        decay = np.exp(-(ts[after] - c.self_recal_jump_time_s) / c.self_recal_settle_tau_s)
        norm_gain[after] = 1.0 + c.self_recal_settle_frac + (c.self_recal_jump_frac - c.self_recal_settle_frac) * decay
    scale = 1.0 + c.scale_sd * rng.normal(size=3)
    sd = c.noise_sd_mps2 * np.clip(1.0 + pose_field_at(spread, kin, t)[:, 0], *c.noise_factor_range)
    extra: dict[str, np.ndarray] = {}
    if c.vibration_mps2_per_mps > 0 or c.compliance_deg_per_mps2 > 0:
        f, extra = _accel_motion(kin, sc, const, t, f, rng.spawn(1)[0])
    vals = f * scale * norm_gain[:, None] + c.bias_sd_mps2 * rng.normal(size=3) + sd[:, None] * rng.normal(size=f.shape)
    arr = arrival(t, c.latency_ms, c.latency_jitter_ms, rng)
    return Stream("accel", t, dev, arr, vals, extra=extra)


def _accel_motion(
    kin: Kinematics, sc: Scenario, const: BenchConstants, t: np.ndarray, f: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Specific force [m/s^2] with mount compliance and vibration (see motion_terms)."""
    c = sc.accel
    R_imu = _interp_R(t, kin.t_ns, kin.R_base_imu)
    a_dyn = f + np.einsum("nji,j->ni", R_imu, G_BASE)  # R^T a: the specific force less gravity's part
    shaft_imu = const.R_tool_imu.T @ np.array([0.0, 0.0, 1.0])
    f = np.einsum("nji,nj->ni", so3_exp(mt.compliance_tilt(a_dyn, shaft_imu, c.compliance_deg_per_mps2)), f)
    dt = np.diff(kin.t_ns).mean() * 1e-9 if len(kin.t_ns) > 1 else 1e-3
    v_tip = np.linalg.norm(np.gradient(kin.p_tip_base_m, dt, axis=0), axis=1)
    rms = c.vibration_mps2_per_mps * np.interp(t, kin.t_ns, v_tip)
    vib = mt.vibration(rng, t * 1e-9, rms, c.vibration_hz, c.rate_hz)
    return f + vib, {"vibration_mps2": vib}


def tof(kin: Kinematics, sc: Scenario, const: BenchConstants, clock: DeviceClock, rng: np.random.Generator) -> Stream:
    """Raw range [mm] with VL53L0X status; extra: smoothed range (5-sample moving average,
    held so that its total latency is smoothed_latency_ms) and its validity."""
    c = sc.tof
    t, dev = clock.sample_times(c.rate_hz, int(kin.t_ns[-1]), rng)
    moving = c.integration_ms > 0 or c.surface_relief_mm > 0 or c.pose_corr_spread > 1.0
    mrng = rng.spawn(1)[0] if moving else None
    rho_mm = _tof_range_mm(kin, c, const, t, mrng)
    corr_deg = mt.session_corr(mrng, c.pose_corr_deg, c.pose_corr_spread)
    corr_m = mt.session_corr(mrng, c.pose_corr_m, c.pose_corr_spread)
    fld = PoseField(rng, 1, c.pose_sd_mm, np.radians(corr_deg), corr_m)
    spread = PoseField(rng, 1, c.noise_pose_spread, np.radians(corr_deg), corr_m)
    sd = c.noise_sd_mm * np.clip(1.0 + pose_field_at(spread, kin, t)[:, 0], *c.noise_factor_range)
    meas = rho_mm + pose_field_at(fld, kin, t)[:, 0] + ou_process(rng, t * 1e-9, c.repeat_sd_mm, c.repeat_tau_s)
    meas = meas + sd * rng.normal(size=len(t))
    status = np.full(len(t), TofStatus.TOF_STATUS_VALID, dtype=np.int32)
    fail = rng.random(len(t)) < c.dropout_prob
    kinds = np.array(
        [TofStatus.TOF_STATUS_SIGMA_FAIL, TofStatus.TOF_STATUS_SIGNAL_FAIL, TofStatus.TOF_STATUS_PHASE_FAIL]
    )
    status[fail] = rng.choice(kinds, size=int(fail.sum()), p=[0.5, 0.35, 0.15])
    meas[fail] += rng.normal(size=int(fail.sum())) * 8 * c.noise_sd_mm
    oor = ~np.isfinite(rho_mm) | (meas > c.max_range_mm)
    status[oor] = TofStatus.TOF_STATUS_OUT_OF_RANGE
    meas[oor] = c.out_of_range_value_mm
    meas = np.round(np.clip(meas, 0.0, None), 0)  # the sensor reports whole millimetres
    valid = status == TofStatus.TOF_STATUS_VALID
    # firmware moving average over the last W valid ranges, then its output hold
    w = c.smoothed_window
    last = np.where(valid, np.arange(len(t)), 0)
    filled = meas[np.maximum.accumulate(last)]
    cs = np.cumsum(np.concatenate([[0.0], filled]))
    ma = np.full(len(t), np.nan)
    if len(t) >= w:
        ma[w - 1 :] = (cs[w:] - cs[:-w]) / w
    nvalid = np.convolve(valid.astype(float), np.ones(w))[: len(t)]
    period_ms = 1e3 / c.rate_hz
    hold = max(0.0, c.smoothed_latency_ms - c.latency_ms - (w - 1) / 2 * period_ms) / period_ms
    idx = np.arange(len(t)) - hold
    smoothed = np.interp(idx, np.arange(len(t)), np.nan_to_num(ma), left=np.nan)
    ok = (np.isfinite(ma) & (nvalid >= w)).astype(float)
    sm_valid = np.interp(idx, np.arange(len(t)), ok, left=0.0) > 0.999
    arr = arrival(t, c.latency_ms, c.latency_jitter_ms, rng)
    return Stream(
        "tof",
        t,
        dev,
        arr,
        meas,
        status,
        extra={
            "smoothed_mm": np.nan_to_num(smoothed),
            "smoothed_valid": sm_valid,
            "true_mm": rho_mm,
            "pose_corr": np.array([corr_deg, corr_m]),
        },
    )


def _tof_range_mm(
    kin: Kinematics, c: Any, const: BenchConstants, t: np.ndarray, rng: np.random.Generator | None
) -> np.ndarray:
    """Range [mm] each sample reports before noise: the ray-plane range, averaged over the
    ranging time and, with surface relief, over the beam footprint (see motion_terms)."""
    offsets = mt.integration_offsets_ns(c.integration_ms)
    relief = None
    if rng is not None and c.surface_relief_mm > 0:
        relief = mt.SurfaceRelief(rng, c.surface_relief_mm * 1e-3, c.surface_corr_mm * 1e-3)
        axes = mt.plane_axes(const.tof_plane_normal_base)
    out = np.zeros(len(t))
    for o in offsets:
        tq = np.clip(t + o, kin.t_ns[0], kin.t_ns[-1])
        R = _interp_R(tq, kin.t_ns, kin.R_base_tool)
        p = _interp(tq, kin.t_ns, kin.p_tip_base_m)
        rho = const.tof_range_m(R, p)
        if relief is not None:
            src = p + np.einsum("nij,j->ni", R, const.tof_origin_tool_m)
            beam = np.einsum("nij,j->ni", R, const.tof_beam_tool)
            hit = src + np.nan_to_num(rho)[:, None] * beam
            sd_fp = np.nan_to_num(rho) * np.tan(np.radians(c.beam_fov_deg) / 2.0) / 2.0
            rho = rho + relief(hit @ axes.T, sd_fp) / np.maximum(beam @ const.tof_plane_normal_base, 1e-3)
        out += rho
    return out / len(offsets) * 1e3


def mag(kin: Kinematics, sc: Scenario, const: BenchConstants, clock: DeviceClock, rng: np.random.Generator) -> Stream:
    """Magnetometer [uT]: Earth field plus a pose-dependent disturbance, scaled per session."""
    c = sc.mag
    t, dev = clock.sample_times(c.rate_hz, int(kin.t_ns[-1]), rng)
    inc, dec = np.radians(c.inclination_deg), np.radians(c.declination_deg)
    B = c.earth_field_ut * np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), -np.sin(inc)])
    dist = PoseField(rng, 3, c.pose_disturbance_sd_ut, np.radians(c.pose_corr_deg), c.pose_corr_m)
    scale = rng.uniform(min(c.session_scale_min, c.session_scale_max), max(c.session_scale_min, c.session_scale_max))
    B_t = scale * (B + pose_field_at(dist, kin, t))
    R_imu = _interp_R(t, kin.t_ns, kin.R_base_imu)
    vals = np.einsum("nji,nj->ni", R_imu, B_t) + c.hard_iron_sd_ut * rng.normal(size=3)
    vals = vals + c.noise_sd_ut * rng.normal(size=vals.shape)
    arr = arrival(t, c.latency_ms, c.latency_jitter_ms, rng)
    return Stream("mag", t, dev, arr, vals, extra={"session_scale": np.array([scale])})


def simulate_sensors(
    gt: Any, sc: Scenario, const: BenchConstants, rng: np.random.Generator
) -> tuple[Kinematics, DeviceClock, dict[str, Stream]]:
    """All four device streams of a session from its ground truth (seeded)."""
    kin = kinematics(gt, const)
    clock = DeviceClock.draw(sc.clock, rng)
    streams = {f.__name__: f(kin, sc, const, clock, rng) for f in (gyro, accel, tof, mag)}
    return kin, clock, streams
