"""The real IMU of the BROAD tuning trials beside the bench's IMU models, by the same statistics.

A plausibility check of the bench's BNO085-class models (`services/bench/sensors/device.py`),
not a copy: BROAD's IMU (myon aktos-t, 285.7 Hz, moved by hand) is another sensor. Every
statistic below runs on the real trials (default: shared/data/broad-tuning beside the
repository) and on the bench sessions given, by the same code:

- at rest (the trials' still phases, the bench's pre/post/hold windows): the overlapping Allan
  deviation of each gyro and accelerometer axis, pooled over axes and windows, fitted as
  sigma^2 = N^2 / tau + (0.664 B)^2 + K^2 tau / 3 (white-noise density N, bias instability B,
  rate random walk K) over 2 samples to an eighth of the longest window;
- the gyro bias's change over each motion between two rests (rest mean after less before),
  beside the bench model's SD for that motion, sqrt(integral of (q0 + q1 |w|)^2 dt);
- in motion: the accelerometer's RMS in bands of 5-10, 10-20, 20-40 and 40-90 Hz and above
  15 Hz, each less the rest's in quadrature, and above 15 Hz per m/s of the sensor's RMS speed
  (the bench's `accel.vibration_mps2_per_mps` is that ratio against the tip's speed); the
  gyro's RMS above 15 Hz, less the rest's alike;
- the gyro against the truth (optical on BROAD, the robot on the bench), both band-passed to
  0.2-3 Hz in motion (the bias's wander lies below): the fit meas = M truth, whose diagonal less
  one is the scale error and whose largest off-diagonal entry is cross-axis sensitivity and
  residual misalignment together, over the axes the motion turns (SD 2 deg/s or more; the
  cross-axis figure only where it turns all three, as an axis left out leaks into the others);
- the accelerometer's norm at rest against the recording's gravity. Its scale and cross-axis
  need many still orientations; BROAD's trials rest in one pose at each end.

    python -m benchmarks.imu_real_vs_bench [--data DIR] [SESSION.mcap ...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import nnls
from scipy.signal import butter, sosfiltfilt

from benchmarks.attitude_real import DATA_DIR, load_trial, trials

DEG = np.pi / 180.0
G_BERLIN = 9.8128  # m/s^2, normal gravity at BROAD's lab (52.5 deg N, near sea level)
BANDS_HZ = ((5.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 90.0))
HIGH_HZ = 15.0


@dataclass
class Recording:
    """One IMU recording: samples at their sensing times [s], the truth (sensor to world and
    the sensor's position, NaN where unknown), rest windows [s] and the truth rows in motion."""

    name: str
    gyro_t_s: np.ndarray
    gyro_radps: np.ndarray
    acc_t_s: np.ndarray
    acc_mps2: np.ndarray
    truth_t_s: np.ndarray
    R_world_imu: np.ndarray
    p_world_imu_m: np.ndarray
    rest_s: list[tuple[float, float]]
    moving: np.ndarray
    g_mps2: float


def broad(path: Path, edge_s: float = 2.0) -> Recording:
    """A BROAD trial: rest is the still phase before the movement and the one after, `edge_s`
    from the movement and 1 s from the file's ends."""
    from scipy.io import loadmat

    from tiplog.geometry import quat_to_rot

    tr = load_trial(path)
    t, m = tr["t_s"], tr["movement"]
    idx = np.flatnonzero(m)
    q = tr["q_opt"]
    R = quat_to_rot(np.column_stack([q[:, 1:], q[:, :1]]))  # x y z w
    p = np.asarray(loadmat(path)["opt_pos"], dtype=float)
    rest = [(t[0] + 1.0, t[idx[0]] - edge_s), (t[idx[-1]] + edge_s, t[-1] - 1.0)]
    return Recording(path.stem, t, tr["gyr"], t, tr["acc"], t, R, p, rest, m, G_BERLIN)


def bench(path: Path) -> Recording:
    """A bench session: samples at host arrival less the scenario's latency, truth from the
    robot and the true IMU mounting, rest from the stationary windows."""
    import yaml

    from services.bench.report import data
    from services.bench.sensors.device import G_BASE

    s = data.load(path)
    sc = yaml.safe_load(s.meta["scenario"]["yaml"])
    gy, ac = s.streams["gyro"], s.streams["accel"]
    t = s.robot_t * 1e-9
    R = s.robot_R @ s.truth.R_tool_imu
    p = s.robot_p + np.einsum("nij,j->ni", s.robot_R, s.truth.p_imu_tool_m)
    rest = [(a * 1e-9, b * 1e-9) for a, b in data.rest_windows(s)]
    return Recording(
        Path(path).stem,
        gy["t"] * 1e-9 - sc["gyro"]["latency_ms"] * 1e-3,
        np.asarray(gy["v"], float),
        ac["t"] * 1e-9 - sc["accel"]["latency_ms"] * 1e-3,
        np.asarray(ac["v"], float),
        t,
        R,
        p,
        rest,
        ~np.isin(s.robot_phase, data.REST),
        float(-G_BASE[2]),
    )


# --- statistics (pure numpy) ------------------------------------------------------------------
def allan_variance(x: np.ndarray, rate_hz: float, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan variance of x (N,) at cluster sizes m (samples): (variance, terms)."""
    theta = np.concatenate([[0.0], np.cumsum(x)]) / rate_hz
    var, n = np.full(len(m), np.nan), np.zeros(len(m), int)
    for i, k in enumerate(m):
        d = theta[2 * k :] - 2.0 * theta[k:-k] + theta[: -2 * k]
        if len(d):
            tau = k / rate_hz
            var[i], n[i] = np.mean(d**2) / (2.0 * tau**2), len(d)
    return var, n


def pooled_adev(segments: list[np.ndarray], rate_hz: float, n_tau: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Allan deviation (taus [s], sigma) pooled over segments (each (N, 3), one sample grid):
    every axis's variance weighted by its terms, taus from 2 samples to 1/8 of the longest."""
    longest = max(len(s) for s in segments)
    m = np.unique(np.round(np.logspace(np.log10(2), np.log10(max(longest // 8, 3)), n_tau)).astype(int))
    num, den = np.zeros(len(m)), np.zeros(len(m))
    for seg in segments:
        for k in range(seg.shape[1]):
            v, n = allan_variance(seg[:, k] - seg[:, k].mean(), rate_hz, m)
            ok = n > 0
            num[ok] += v[ok] * n[ok]
            den[ok] += n[ok]
    keep = den > 0
    return m[keep] / rate_hz, np.sqrt(num[keep] / den[keep])


def noise_fit(taus: np.ndarray, adev: np.ndarray) -> dict[str, float]:
    """N (white density, units/rtHz), B (bias instability), K (random walk, units*rtHz) of
    sigma^2 = N^2/tau + (0.664 B)^2 + K^2 tau/3, non-negative, in relative terms."""
    A = np.column_stack([1.0 / taus, np.full(len(taus), 0.664**2), taus / 3.0]) / adev[:, None] ** 2
    c, _ = nnls(A, np.ones(len(taus)))
    return {"N": float(np.sqrt(c[0])), "B": float(np.sqrt(c[1])), "K": float(np.sqrt(c[2]))}


def band_rms(x: np.ndarray, rate_hz: float, lo_hz: float, hi_hz: float | None, mask: np.ndarray) -> float:
    """RMS of the vector norm of x (N, 3) band-passed (zero phase) to [lo, hi] Hz over mask."""
    hi = None if hi_hz is None else min(hi_hz, 0.45 * rate_hz)
    if hi is None:
        sos = butter(4, lo_hz, btype="high", fs=rate_hz, output="sos")
    else:
        sos = butter(4, [lo_hz, hi], btype="band", fs=rate_hz, output="sos")
    y = sosfiltfilt(sos, x - x.mean(0), axis=0)[mask]
    return float(np.sqrt(np.mean(np.sum(y**2, axis=1)))) if len(y) else float("nan")


def linear_fit(meas: np.ndarray, truth: np.ndarray, min_sd: float, intercept: bool) -> tuple[np.ndarray, float]:
    """Least squares meas (N, 3) = M truth (N, 3) (+ b): (M with NaN columns for the truth
    axes whose SD is under min_sd, which leave the fit, residual RMS per axis)."""
    cols = np.flatnonzero(truth.std(axis=0) >= min_sd)
    X = truth[:, cols]
    if intercept:
        X = np.column_stack([X, np.ones(len(truth))])
    coef, *_ = np.linalg.lstsq(X, meas, rcond=None)
    M = np.full((3, 3), np.nan)
    M[:, cols] = coef[: len(cols)].T
    return M, float(np.sqrt(np.mean((meas - X @ coef) ** 2)))


# --- on a recording ---------------------------------------------------------------------------
def _rate(t: np.ndarray) -> float:
    return 1.0 / float(np.median(np.diff(t)))


def _in(t: np.ndarray, windows: list[tuple[float, float]]) -> np.ndarray:
    out = np.zeros(len(t), bool)
    for a, b in windows:
        out |= (t >= a) & (t <= b)
    return out


def _lowpass(x: np.ndarray, rate_hz: float, hz: float) -> np.ndarray:
    return sosfiltfilt(butter(2, hz, fs=rate_hz, output="sos"), x, axis=0)


def _truth_filled(r: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth rotations and positions with gaps interpolated (rotation vectors about the
    previous good row), and the rows 0.5 s or more from any gap."""
    from scipy.ndimage import binary_dilation

    from tiplog.geometry import so3_exp, so3_log

    ok = np.isfinite(r.R_world_imu).all((1, 2)) & np.isfinite(r.p_world_imu_m).all(1)
    good = np.flatnonzero(ok)
    R, p = r.R_world_imu.copy(), r.p_world_imu_m.copy()
    if len(good) < len(ok):
        ref = R[good[0]]
        rv = so3_log(np.einsum("ji,njk->nik", ref, R[good]))
        rvi = np.column_stack([np.interp(r.truth_t_s, r.truth_t_s[good], rv[:, k]) for k in range(3)])
        R = ref @ so3_exp(rvi)
        p = np.column_stack([np.interp(r.truth_t_s, r.truth_t_s[good], p[good, k]) for k in range(3)])
    n = int(0.5 * _rate(r.truth_t_s))
    far = ~binary_dilation(~ok, iterations=n) if n and not ok.all() else ok
    return R, p, far


def body_rate(t: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Body angular rate (N, 3) [rad/s] of rotations R (N, 3, 3) by central differences."""
    from tiplog.geometry import so3_log

    w = np.zeros((len(t), 3))
    w[1:-1] = so3_log(np.einsum("nji,njk->nik", R[:-2], R[2:])) / (t[2:] - t[:-2])[:, None]
    w[0], w[-1] = w[1], w[-2]
    return w


def _interp(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(tq, t, y[:, k]) for k in range(y.shape[1])])


def statistics(r: Recording) -> dict:
    """Every statistic of the module docstring on one recording (units in the keys)."""
    fg, fa = _rate(r.gyro_t_s), _rate(r.acc_t_s)
    out: dict = {"name": r.name, "rest_s": float(sum(b - a for a, b in r.rest_s))}
    g_rest = [r.gyro_radps[_in(r.gyro_t_s, [w])] for w in r.rest_s]
    a_rest = [r.acc_mps2[_in(r.acc_t_s, [w])] for w in r.rest_s]
    taus, sg = pooled_adev([s / DEG for s in g_rest if len(s) > 16], fg)
    out["gyro"] = {**noise_fit(taus, sg), "tau_max_s": float(taus[-1])}
    taus, sa = pooled_adev([s for s in a_rest if len(s) > 16], fa)
    out["acc"] = {**noise_fit(taus, sa), "tau_max_s": float(taus[-1])}
    a_rest = [s for s in a_rest if len(s) > 16]
    out["acc"]["sd_mps2"] = float(np.mean([np.sqrt(np.mean(np.var(s, axis=0))) for s in a_rest]))
    norm = np.mean([np.linalg.norm(s.mean(axis=0)) for s in a_rest])
    out["acc"]["norm_pct"] = float((norm / r.g_mps2 - 1.0) * 100)
    out["bias_change"] = _bias_changes(r)

    mov_g = np.interp(r.gyro_t_s, r.truth_t_s, r.moving.astype(float)) > 0.5
    mov_a = np.interp(r.acc_t_s, r.truth_t_s, r.moving.astype(float)) > 0.5
    rest_a = _in(r.acc_t_s, r.rest_s)
    R, p, far = _truth_filled(r)
    ft = _rate(r.truth_t_s)
    speed = np.linalg.norm(np.gradient(_lowpass(p, ft, 5.0), 1.0 / ft, axis=0), axis=1)
    v_rms = float(np.sqrt(np.mean(speed[r.moving & far] ** 2)))

    rest_g = _in(r.gyro_t_s, r.rest_s)

    def floor_corrected(lo: float, hi: float | None, gyro: bool = False) -> float:
        x, f, mov, rest = (r.gyro_radps / DEG, fg, mov_g, rest_g) if gyro else (r.acc_mps2, fa, mov_a, rest_a)
        m, z = band_rms(x, f, lo, hi, mov), band_rms(x, f, lo, hi, rest)
        return float(np.sqrt(max(m**2 - z**2, 0.0)))

    hf = floor_corrected(HIGH_HZ, None)
    out["motion"] = {
        "speed_rms_mps": v_rms,
        "acc_bands_mps2": [floor_corrected(lo, hi) for lo, hi in BANDS_HZ],
        "acc_high_mps2": hf,
        "acc_high_per_mps": hf / v_rms if v_rms > 0 else float("nan"),
        "gyro_high_dps": floor_corrected(HIGH_HZ, None, gyro=True),
        "gyro_rms_dps": float(np.sqrt(np.mean(np.sum(r.gyro_radps[mov_g] ** 2, axis=1)))) / DEG,
    }
    out["gyro_scale"] = _gyro_scale(r, R, far)
    return out


def _bias_changes(r: Recording) -> list[dict]:
    """Per motion between two rests: the gyro's rest mean after less before [deg/s] and the
    bench model's SD of that change for the motion's measured rates."""
    from services.bench.scenario import GyroConfig

    c = GyroConfig()
    fg = _rate(r.gyro_t_s)
    out = []
    for (a0, a1), (b0, b1) in zip(r.rest_s[:-1], r.rest_s[1:], strict=True):
        before = r.gyro_radps[_in(r.gyro_t_s, [(a0, a1)])].mean(0)
        after = r.gyro_radps[_in(r.gyro_t_s, [(b0, b1)])].mean(0)
        w = np.linalg.norm(r.gyro_radps[(r.gyro_t_s > a1) & (r.gyro_t_s < b0)], axis=1)
        q = c.bias_rw_static_dps_rts + c.bias_rw_motion_dps_rts_per_radps * w
        turned_deg = float(w.sum() / fg / DEG)
        model = float(np.sqrt(np.sum(q**2) / fg))
        out.append({"change_dps": ((after - before) / DEG).tolist(), "model_sd_dps": model, "turned_deg": turned_deg})
    return out


def _gyro_scale(r: Recording, R: np.ndarray, far: np.ndarray) -> dict:
    """The gyro's fit against the truth on 0.2-3 Hz in motion (the bias's wander lies below); a
    truth axis that turns too little (SD under 2 deg/s) leaves its column out."""
    fg = _rate(r.gyro_t_s)
    w_body = body_rate(r.truth_t_s, R)
    band = butter(2, [0.2, 3.0], btype="band", fs=fg, output="sos")
    wt = sosfiltfilt(band, _interp(r.gyro_t_s, r.truth_t_s, w_body), axis=0)
    wm = sosfiltfilt(band, r.gyro_radps, axis=0)
    far_g = np.interp(r.gyro_t_s, r.truth_t_s, far.astype(float)) > 0.999
    mov_g = np.interp(r.gyro_t_s, r.truth_t_s, r.moving.astype(float)) > 0.5
    use = far_g & mov_g
    if use.sum() > 100:
        M, res = linear_fit(wm[use] / DEG, wt[use] / DEG, 2.0, False)
        return _scale_row(M, res)
    return {}


def _scale_row(M: np.ndarray, res: float) -> dict:
    off = M - np.diag(np.diag(M))
    return {
        "scale_pct": [float(x) for x in (np.diag(M) - 1.0) * 100],
        "cross_pct": float(np.abs(off).max() * 100) if np.isfinite(M).all() else float("nan"),
        "res": res,
    }


# --- table ------------------------------------------------------------------------------------
def _fmt_scale(d: dict | None) -> str:
    s = [x for x in (d or {}).get("scale_pct", []) if np.isfinite(x)]
    if not s:
        return "-"
    cross = f"{d['cross_pct']:.2f}" if np.isfinite(d["cross_pct"]) else "-"
    return f"{min(s):+.2f}..{max(s):+.2f} / {cross} ({len(s)})"


def table(rows: list[dict]) -> str:
    """The printed tables: rest, then motion and truth fits."""
    lines = [
        "at rest (Allan deviation fit; tau up to tau_max)",
        f"{'recording':<34} {'rest s':>6} {'gyro N':>8} {'gyro B':>7} {'gyro K':>7} {'tau_max':>7} "
        f"{'acc N':>7} {'acc sd':>6} {'|a|-g':>6} {'bias change / model SD (turned)':>32}",
        f"{'':<34} {'':>6} {'dps/rHz':>8} {'dps':>7} {'dps*rHz':>7} {'s':>7} {'mps2/rHz':>7} {'mps2':>6} {'%':>6} {'dps (deg)':>32}",
    ]
    for r in rows:
        g, a = r["gyro"], r["acc"]
        bc = "; ".join(
            f"{np.sqrt(np.mean(np.square(c['change_dps']))):.3f}/{c['model_sd_dps']:.3f} ({c['turned_deg']:.0f})"
            for c in r["bias_change"][:2]
        )
        lines.append(
            f"{r['name'][:34]:<34} {r['rest_s']:6.0f} {g['N']:8.4f} {g['B']:7.4f} {g['K']:7.4f} {g['tau_max_s']:7.1f} "
            f"{a['N']:7.4f} {a['sd_mps2']:6.3f} {a['norm_pct']:+6.2f} {bc:>32}"
        )
    bands = " ".join(f"{f'{lo:g}-{hi:g}':>5}" for lo, hi in BANDS_HZ)
    lines += [
        "",
        "in motion (accelerometer RMS less the rest's, m/s^2; gyro deg/s); gyro against the truth: "
        "scale % min..max / cross-axis % max (axes fitted)",
        f"{'recording':<34} {'speed':>5} {bands} {'>15':>5} {'/(m/s)':>6} {'gyro':>6} {'g>15':>5} "
        f"{'gyro scale / cross':>26}",
    ]
    for r in rows:
        m = r["motion"]
        b = " ".join(f"{x:5.3f}" for x in m["acc_bands_mps2"])
        lines.append(
            f"{r['name'][:34]:<34} {m['speed_rms_mps']:5.3f} {b} {m['acc_high_mps2']:5.3f} {m['acc_high_per_mps']:6.2f} "
            f"{m['gyro_rms_dps']:6.1f} {m['gyro_high_dps']:5.2f} {_fmt_scale(r['gyro_scale']):>26}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.imu_real_vs_bench", description=__doc__.split("\n")[0])
    ap.add_argument("sessions", nargs="*", help="bench sessions (tiplog sim generate)")
    ap.add_argument("--data", default=str(DATA_DIR), help="folder of BROAD .mat trials")
    ap.add_argument("--json", help="write every statistic here")
    args = ap.parse_args(argv)
    recs = [broad(p) for p in trials(Path(args.data))]
    for s in args.sessions:
        if not Path(s).is_file():
            print(f"imu_real_vs_bench: no session file {s}", file=sys.stderr)
            return 2
    recs += [bench(Path(s)) for s in args.sessions]
    if not recs:
        print(f"imu_real_vs_bench: no .mat trials in {args.data} and no sessions", file=sys.stderr)
        return 2
    rows = [statistics(r) for r in recs]
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
