"""Six-axis attitude filter: gyroscope and accelerometer to the sensor's orientation in an earth
frame with z up (heading arbitrary, no magnetometer). Pure numpy, no I/O.

The structure follows VQF's 6-D part (Laidig and Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information Fusion 2023):

- the gyroscope is integrated strapdown into a quasi-inertial frame (`q_gyr`);
- the accelerometer is rotated into that frame and low-passed there (second-order Butterworth,
  time constant `tau_acc_s`): motion accelerations average out in an inertial frame while
  gravity does not, so the filtered vector is gravity as the drifting gyro frame sees it;
- an inclination correction `q_acc` (about horizontal axes only) turns it onto +z;
- the gyroscope bias is a three-state Kalman filter, fed at rest by the mean rate of the rest
  detector's latest chunk and in motion by the rate of the inclination correction. Rest is the
  tracking filter's detector (`kernels.rest`): VQF's test (every sample near its
  low-pass for `rest_min_s`), then chunks of `rest_chunk_s` taken only once the next chunk
  agrees with them, so that a slow sway is not rest; a chunk whose mean rate is beyond the
  bias clip is a slow turn, not rest.

Unlike VQF, every step uses its own time step from the sample stamps (arbitrary and jittering
rates, dropped rows); as in VQF, a gyroscope sample is the mean rate over the step that ends at
its stamp (what a MEMS gyroscope's decimation filter puts out), so the step turns by that
sample, not by the mean of it and the previous one, which would lag half a step; a gap longer than
`max_gap_s` restarts the inclination from the next accelerometer sample, and a missing (NaN)
gyroscope or accelerometer value skips that sensor for the row, and a gyroscope that lags its
stamps (`gyr_delay_s`, a sensor's internal filtering) has its integrated orientation carried
forward over the delay by its latest bias-corrected rate before the accelerometer and the
output use it. The time loop is one scalar
kernel, compiled with numba (a dependency; when it is missing the same code runs as plain
Python, slower, same results); the online `update` and the batch `update_batch` share it.

Quaternions here are Hamilton (w, x, y, z), sensor to earth: v_earth = q * v_sensor * q^-1.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from services.fusion.eskf import jit_cache
from services.fusion.eskf.kernels.rest import rest_init, rest_sample
from services.fusion.eskf.kernels.so3 import quat_matrix, quat_mul
from services.fusion.eskf.layout import REST_RATE, rest_constants

# numba, a dependency, compiles the time loop (about 100x faster); plain Python where it is absent
HAVE_NUMBA = jit_cache.numba is not None


def jit(f):
    # through `jit_cache.njit`: numba keys this module's cache on this file alone, and the rest
    # detector, the quaternion helpers (eskf/kernels/) and layout.py's constants are compiled in
    # too, so the cache goes when any file the filter's kernels compile in changes
    return jit_cache.njit(cache=True, nogil=True)(f)


_DEG = math.pi / 180.0
_SQRT2 = math.sqrt(2.0)

# Layout of the flat state vector the kernel works on.
_QG, _QA, _LPA, _BIAS, _P = 0, 4, 8, 14, 17  # q_gyr(4) q_acc(4) acc lp(6) bias(3) P(9)
_GLP, _LPR, _LPB = 26, 29, 47  # rest's mean gyro rate(3) R lp(18) Rb lp(4)
_REST, _T, _GPREV, _FLAG, _ACC_INIT, _ACC_T = 51, 52, 53, 56, 57, 58
_N_STATE = 59
# Layout of the kernel's parameter vector (`Params.vector`).
PRM_TAU_ACC_S, PRM_BIAS_SIGMA_INIT_DPS, PRM_BIAS_FORGETTING_S, PRM_BIAS_CLIP_RADPS = 0, 1, 2, 3
PRM_BIAS_SIGMA_MOTION_DPS, PRM_VERTICAL_FORGETTING, PRM_BIAS_SIGMA_REST_DPS = 4, 5, 6
PRM_MAX_GAP_S = 7  # negative when the bias is not estimated
PRM_GYR_DELAY_S = 8
PRM_SIZE = 9


@dataclass(frozen=True)
class Params:
    """Filter parameters; angles in degrees, rates in deg/s, times in seconds."""

    tau_acc_s: float = 3.0  # accelerometer low-pass time constant in the quasi-inertial frame
    bias_sigma_init_dps: float = 0.5  # prior of the gyroscope bias
    bias_forgetting_time_s: float = 100.0  # bias variance grows to (0.1 deg/s)^2 in this time
    bias_clip_dps: float = 2.0  # bias estimate and its per-step disagreement are clipped to this
    bias_sigma_motion_dps: float = 0.1  # steady-state bias sigma with motion updates alone
    bias_vertical_forgetting: float = 1e-4  # weight of the vertical pseudo-update in motion
    bias_sigma_rest_dps: float = 0.03  # steady-state bias sigma with rest updates
    rest_th_gyr_dps: float = 2.0  # rest: |gyr - lp(gyr)| below this ...
    rest_th_acc_mps2: float = 0.5  # ... and |acc - lp(acc)| below this ...
    rest_min_s: float = 1.5  # ... for this long; then chunks of
    rest_chunk_s: float = 0.5  # this long are rest when the next one's mean rate ...
    rest_agree_gyr_dps: float = 0.1  # ... is within this of theirs ...
    rest_agree_acc_mps2: float = 0.05  # ... and its mean specific force within this
    max_gap_s: float = 0.5  # a longer gap between rows restarts the inclination
    rest_tau_s: float = 0.5  # low-pass time constant of rest detection (first order)
    gyr_delay_s: float = 0.0  # the gyroscope's samples lag their stamps (and the accelerometer) by this
    estimate_bias: bool = True

    def __post_init__(self) -> None:
        for name, v in asdict(self).items():
            if name == "estimate_bias":
                continue
            if name == "gyr_delay_s":
                if not (isinstance(v, (int, float)) and 0.0 <= v <= 0.1):
                    raise ValueError(f"attitude parameter gyr_delay_s: must be from 0 to 0.1 s (got {v!r})")
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"attitude parameter {name}: must be a finite number > 0 (got {v!r})")

    def vector(self) -> np.ndarray:
        """The kernel's parameter vector (radians and SI units; the rest detector's: `rest_vector`)."""
        v = np.empty(PRM_SIZE)
        v[PRM_TAU_ACC_S] = self.tau_acc_s
        v[PRM_BIAS_SIGMA_INIT_DPS] = self.bias_sigma_init_dps
        v[PRM_BIAS_FORGETTING_S] = self.bias_forgetting_time_s
        v[PRM_BIAS_CLIP_RADPS] = self.bias_clip_dps * _DEG
        v[PRM_BIAS_SIGMA_MOTION_DPS] = self.bias_sigma_motion_dps
        v[PRM_VERTICAL_FORGETTING] = self.bias_vertical_forgetting
        v[PRM_BIAS_SIGMA_REST_DPS] = self.bias_sigma_rest_dps
        v[PRM_MAX_GAP_S] = self.max_gap_s if self.estimate_bias else -self.max_gap_s
        v[PRM_GYR_DELAY_S] = self.gyr_delay_s
        return v

    def rest_vector(self) -> np.ndarray:
        """The constants of `kernels.rest.rest_sample`, the rest detector the tracking filter uses."""
        return rest_constants(
            self.rest_tau_s, self.rest_th_gyr_dps * _DEG, self.rest_th_acc_mps2, self.rest_min_s, self.rest_chunk_s,
            self.max_gap_s, self.rest_agree_gyr_dps * _DEG, self.rest_agree_acc_mps2,
        )  # fmt: skip


@jit
def lowpass_coeffs(tau: float, dt: float) -> tuple[float, float, float, float, float, float]:
    """Second-order Butterworth low-pass (natural frequency sqrt(2)/tau) in state-space form
    (value, rate), discretised by the trapezoid rule for a step dt: stable for any dt, and
    the steady state of a constant input is (input, 0) whatever dt was, so jittering steps
    cause no transients. Returns (m11, m12, m21, m22, n1, n2)."""
    w = _SQRT2 / tau
    a = 0.5 * dt
    d = 1.0 + _SQRT2 * w * a + w * w * a * a
    return (
        (1.0 + _SQRT2 * w * a - w * w * a * a) / d,
        2.0 * a / d,
        -2.0 * w * w * a / d,
        (1.0 - _SQRT2 * w * a - w * w * a * a) / d,
        a * w * w * dt / d,
        w * w * dt / d,
    )


@jit
def lowpass(x: float, c: tuple[float, float, float, float, float, float], s: np.ndarray, k: int) -> float:
    """One step of the low-pass on channel state s[k] (value), s[k + 1] (rate); returns the value."""
    y = c[0] * s[k] + c[1] * s[k + 1] + c[4] * x
    s[k + 1] = c[2] * s[k] + c[3] * s[k + 1] + c[5] * x
    s[k] = y
    return y


@jit
def _lp_init(x: float, s: np.ndarray, k: int) -> None:
    """Channel state s[k], s[k + 1] at rest on a constant input x."""
    s[k] = x
    s[k + 1] = 0.0


@jit
def _run(
    t_s: np.ndarray,
    gyr: np.ndarray,
    acc: np.ndarray,
    prm: np.ndarray,
    st: np.ndarray,
    q_out: np.ndarray,
    b_out: np.ndarray,
    rest: np.ndarray,
    rest_k: np.ndarray,
) -> None:
    """Advance state `st` over rows (t_s (N,), gyr (N, 3) rad/s, acc (N, 3) m/s^2, NaN = missing);
    writes the sensor-to-earth quaternion of every row into q_out (N, 4) and the bias into
    st; when b_out has N rows, each row's bias [rad/s] and its covariance [(deg/s)^2] into
    b_out (N, 12). `rest` is the state of the rest detector (`kernels.rest.rest_sample`, constants
    rest_k). Rows whose time is not after the previous row's change nothing."""
    clip, max_gap = prm[PRM_BIAS_CLIP_RADPS], abs(prm[PRM_MAX_GAP_S])
    qtmp = np.empty(4)
    qnow = st[_QG : _QG + 4].copy()  # q_gyr carried forward over the gyroscope's delay
    delay = prm[PRM_GYR_DELAY_S]
    corr = np.empty(4)
    R = np.empty(9)
    H = np.zeros((3, 3))
    e = np.zeros(3)
    for i in range(t_s.shape[0]):
        t = t_s[i]
        g_ok = math.isfinite(gyr[i, 0]) and math.isfinite(gyr[i, 1]) and math.isfinite(gyr[i, 2])
        a_ok = math.isfinite(acc[i, 0]) and math.isfinite(acc[i, 1]) and math.isfinite(acc[i, 2])
        a_ok = a_ok and (acc[i, 0] != 0.0 or acc[i, 1] != 0.0 or acc[i, 2] != 0.0)
        if st[_FLAG] == 0.0:
            st[_FLAG] = 1.0
            st[_T] = t
            dt = 0.0
        else:
            dt = t - st[_T]
            if not dt > 0.0:  # a repeated stamp: nothing happened since the previous row
                quat_mul(st[_QA : _QA + 4], qnow, q_out[i])
                if b_out.shape[0] == t_s.shape[0]:
                    for k in range(12):
                        b_out[i, k] = st[_BIAS + k]
                continue
            st[_T] = t
            if dt > max_gap:  # orientation over the gap is unknown: restart the inclination
                st[_ACC_INIT] = 0.0
                st[_REST] = 0.0
            elif g_ok or st[_GPREV] == st[_GPREV]:
                # the sample is the mean rate over the step that ends at its stamp (a missing
                # one: the previous sample held)
                for k in range(3):
                    gc = gyr[i, k] if g_ok else st[_GPREV + k]
                    e[k] = (gc - st[_BIAS + k]) * dt
                ang = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
                if ang > 1e-15:
                    s = math.sin(0.5 * ang) / ang
                    qtmp[0], qtmp[1], qtmp[2], qtmp[3] = math.cos(0.5 * ang), s * e[0], s * e[1], s * e[2]
                    quat_mul(st[_QG : _QG + 4], qtmp, st[_QG : _QG + 4])
        if g_ok:
            for k in range(3):
                st[_GPREV + k] = gyr[i, k]
            # a chunk's mean rate released as rest (one beyond the bias clip is a slow turn)
            if rest_sample(rest, gyr[i], t, 0, rest_k):
                big = False
                for k in range(3):
                    big = big or abs(rest[REST_RATE + k]) > clip
                if not big:
                    st[_REST] = 1.0
                    for k in range(3):
                        st[_GLP + k] = rest[REST_RATE + k]
        if a_ok:
            rest_sample(rest, acc[i], t, 1, rest_k)
        if rest[8] != rest[8]:  # a sample off its low-pass: moving
            st[_REST] = 0.0
        _predict(st, delay, qnow, qtmp, e)
        if a_ok:
            _acc_step(acc[i], dt, st, prm, qnow, qtmp, corr, R, H, e)
        quat_mul(st[_QA : _QA + 4], qnow, q_out[i])
        if b_out.shape[0] == t_s.shape[0]:
            for k in range(12):
                b_out[i, k] = st[_BIAS + k]


@jit
def _predict(st: np.ndarray, delay: float, qnow: np.ndarray, qr: np.ndarray, e: np.ndarray) -> None:
    """qnow: q_gyr carried over the gyroscope's delay by its latest bias-corrected rate, so
    that the accelerometer and the output see the orientation at the row's stamp."""
    for k in range(4):
        qnow[k] = st[_QG + k]
    if delay <= 0.0 or st[_GPREV] != st[_GPREV]:
        return
    for k in range(3):
        e[k] = (st[_GPREV + k] - st[_BIAS + k]) * delay
    ang = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    if ang > 1e-15:
        s = math.sin(0.5 * ang) / ang
        qr[0], qr[1], qr[2], qr[3] = math.cos(0.5 * ang), s * e[0], s * e[1], s * e[2]
        quat_mul(st[_QG : _QG + 4], qr, qnow)


@jit
def _acc_step(a, dt, st, prm, qnow, qtmp, corr, R, H, e) -> None:
    """Accelerometer row: low-pass in the gyro frame, inclination correction, bias update (see
    the module docstring)."""
    tau_acc, clip = prm[PRM_TAU_ACC_S], prm[PRM_BIAS_CLIP_RADPS]
    mot_sig, vert_f, rest_sig = (
        prm[PRM_BIAS_SIGMA_MOTION_DPS],
        prm[PRM_VERTICAL_FORGETTING],
        prm[PRM_BIAS_SIGMA_REST_DPS],
    )
    bias_on = prm[PRM_MAX_GAP_S] > 0
    p0 = prm[PRM_BIAS_SIGMA_INIT_DPS] * prm[PRM_BIAS_SIGMA_INIT_DPS]
    v_rate = 0.01 / prm[PRM_BIAS_FORGETTING_S]  # (0.1 deg/s)^2 per forgetting time, per second
    init = st[_ACC_INIT] == 0.0 or dt <= 0.0
    step = dt if dt > 0.0 else 0.005
    ca = lowpass_coeffs(tau_acc, step)
    # accelerometer in the quasi-inertial gyro frame, low-passed there
    quat_matrix(qnow, R)
    for k in range(3):
        x = R[3 * k] * a[0] + R[3 * k + 1] * a[1] + R[3 * k + 2] * a[2]
        if init:
            _lp_init(x, st, _LPA + 2 * k)
            e[k] = x
        else:
            e[k] = lowpass(x, ca, st, _LPA + 2 * k)
    # into the earth frame, normalised; correction about horizontal axes onto +z
    quat_matrix(st[_QA : _QA + 4], R)
    ex = R[0] * e[0] + R[1] * e[1] + R[2] * e[2]
    ey = R[3] * e[0] + R[4] * e[1] + R[5] * e[2]
    ez = R[6] * e[0] + R[7] * e[1] + R[8] * e[2]
    n = math.sqrt(ex * ex + ey * ey + ez * ez)
    if n < 1e-9:
        return
    ex, ey, ez = ex / n, ey / n, ez / n
    qw = math.sqrt(max(0.0, (ez + 1.0) * 0.5))
    if qw > 1e-6:
        corr[0], corr[1], corr[2], corr[3] = qw, 0.5 * ey / qw, -0.5 * ex / qw, 0.0
    else:
        corr[0], corr[1], corr[2], corr[3] = 0.0, 1.0, 0.0, 0.0
    quat_mul(corr, st[_QA : _QA + 4], st[_QA : _QA + 4])
    if not bias_on:
        st[_ACC_INIT] = 1.0
        return
    # bias: R of the 6-D orientation and R @ bias, both low-passed like the accelerometer
    quat_mul(st[_QA : _QA + 4], qnow, qtmp)
    quat_matrix(qtmp, R)
    bx, by, bz = st[_BIAS], st[_BIAS + 1], st[_BIAS + 2]
    rb0_ = R[0] * bx + R[1] * by + R[2] * bz
    rb1_ = R[3] * bx + R[4] * by + R[5] * bz
    for k in range(9):
        if init:
            _lp_init(R[k], st, _LPR + 2 * k)
        else:
            R[k] = lowpass(R[k], ca, st, _LPR + 2 * k)
    if init:
        _lp_init(rb0_, st, _LPB)
        _lp_init(rb1_, st, _LPB + 2)
        st[_ACC_INIT] = 1.0
        st[_ACC_T] = 0.0
        return
    rb0_ = lowpass(rb0_, ca, st, _LPB)
    rb1_ = lowpass(rb1_, ca, st, _LPB + 2)
    st[_ACC_T] += dt
    # variances in (deg/s)^2; W chosen so the steady-state sigma is the parameter's
    v = v_rate * dt
    for k in range(3):
        if st[_P + 4 * k] < p0:
            st[_P + 4 * k] += v
    if st[_REST] > 0.0:
        for k in range(3):
            e[k] = st[_GLP + k] - st[_BIAS + k]
            for j in range(3):
                H[k, j] = 1.0 if k == j else 0.0
        pr = rest_sig * rest_sig
        w0 = w1 = w2 = pr * pr / v + pr
    elif st[_ACC_T] < 2.0 * tau_acc:  # the inclination is still settling from its start
        return
    else:
        e[0] = -ey / dt + rb0_ - (R[0] * bx + R[1] * by + R[2] * bz)
        e[1] = ex / dt + rb1_ - (R[3] * bx + R[4] * by + R[5] * bz)
        e[2] = -(R[6] * bx + R[7] * by + R[8] * bz)
        for k in range(3):
            for j in range(3):
                H[k, j] = R[3 * k + j]
        pm = mot_sig * mot_sig
        w0 = w1 = pm * pm / v + pm
        w2 = w0 / max(vert_f, 1e-10)
    e_deg = np.empty(3)
    for k in range(3):
        e_deg[k] = min(max(e[k], -clip), clip) / _DEG
    P = st[_P : _P + 9].reshape(3, 3)
    S = H @ P @ H.T
    S[0, 0] += w0
    S[1, 1] += w1
    S[2, 2] += w2
    K = P @ H.T @ np.linalg.inv(S)
    db = K @ e_deg
    P2 = P - K @ H @ P
    for k in range(9):
        st[_P + k] = P2.ravel()[k]
    for k in range(3):
        st[_BIAS + k] = min(max(st[_BIAS + k] + db[k] * _DEG, -clip), clip)


def input_rows(t_s, gyr_radps, acc_mps2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The filters' input rows as contiguous float arrays (t_s, gyr, acc); ValueError naming
    the shapes unless they are (N,), (N, 3), (N, 3)."""
    t = np.ascontiguousarray(t_s, dtype=float)
    g = np.ascontiguousarray(gyr_radps, dtype=float)
    a = np.ascontiguousarray(acc_mps2, dtype=float)
    n = t.shape[0] if t.ndim else 0
    if t.ndim != 1 or g.shape != (n, 3) or a.shape != (n, 3):
        raise ValueError(
            f"attitude input: expected t_s (N,), gyr (N, 3), acc (N, 3); got {t.shape}, {g.shape}, {a.shape}"
        )
    return t, g, a


class AttitudeFilter:
    """Online and batch use of the kernel; the state carries over between calls, so feeding a
    recording in pieces gives the same result as feeding it at once."""

    def __init__(self, params: Params | None = None):
        self.params = params or Params()
        self._prm = self.params.vector()
        self.reset()

    def reset(self) -> None:
        st = np.zeros(_N_STATE)
        st[_QG] = st[_QA] = 1.0
        st[_P : _P + 9] = (np.eye(3) * self.params.bias_sigma_init_dps**2).ravel()
        st[_GPREV : _GPREV + 3] = np.nan
        self._st = st
        self._rest = rest_init()
        self._rest_k = self.params.rest_vector()
        self._q = np.array([1.0, 0.0, 0.0, 0.0])

    @property
    def quat(self) -> np.ndarray:
        """Latest sensor-to-earth quaternion (w, x, y, z)."""
        return self._q.copy()

    @property
    def bias_radps(self) -> np.ndarray:
        """Current gyroscope bias estimate, sensor axes, rad/s."""
        return self._st[_BIAS : _BIAS + 3].copy()

    @property
    def rest(self) -> bool:
        """Whether rest is detected now."""
        return bool(self._st[_REST] > 0.0)

    def update(self, t_s: float, gyr_radps: np.ndarray, acc_mps2: np.ndarray) -> np.ndarray:
        """One row: time [s], gyro (3,) [rad/s], accelerometer (3,) [m/s^2] (NaN: missing).
        Returns the sensor-to-earth quaternion (w, x, y, z)."""
        return self.update_batch(np.array([t_s], float), np.reshape(gyr_radps, (1, 3)), np.reshape(acc_mps2, (1, 3)))[0]

    def update_batch(
        self, t_s: np.ndarray, gyr_radps: np.ndarray, acc_mps2: np.ndarray, with_bias: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows t_s (N,) [s, increasing], gyr (N, 3) [rad/s], acc (N, 3) [m/s^2] -> (N, 4)
        sensor-to-earth quaternions (w, x, y, z). NaN marks a missing value. With `with_bias`,
        also each row's gyroscope bias estimate (N, 3) [rad/s] and its covariance (N, 3, 3)
        [(deg/s)^2]."""
        t, g, a = input_rows(t_s, gyr_radps, acc_mps2)
        n = t.shape[0]
        out = np.empty((n, 4))
        b_out = np.empty((n if with_bias else 0, 12))
        _run(t, g, a, self._prm, self._st, out, b_out, self._rest, self._rest_k)
        if n:
            self._q = out[-1].copy()
        if with_bias:
            return out, b_out[:, :3].copy(), b_out[:, 3:].reshape(n, 3, 3).copy()
        return out


def estimate(t_s: np.ndarray, gyr_radps: np.ndarray, acc_mps2: np.ndarray, params: Params | None = None) -> np.ndarray:
    """Whole recording at once: (N,) s, (N, 3) rad/s, (N, 3) m/s^2 -> (N, 4) quaternions (w, x, y, z)."""
    return AttitudeFilter(params).update_batch(t_s, gyr_radps, acc_mps2)
