"""The real IMU of the BROAD tuning trials beside the bench's IMU models and both rest detectors.

A plausibility check, not a copy: BROAD's IMU (myon aktos-t, 285.7 Hz) is not the product's
BNO085. For each trial in `--data` (default: shared/data/broad-tuning beside the repository):

- noise at rest (the still phases before and after the movement, 2 s from each edge): gyro
  rate noise density, accelerometer noise per sample and as tilt, the accelerometer's norm;
- gyro bias wander: the mean rate at rest after the movement less the one before, beside what
  the bench's model (random walk q0 + q1 |w| per sqrt(s)) predicts for that trial's rates;
- the gyroscope's lag behind the accelerometer: the shift that best fits d(a/|a|)/dt = -w x a/|a|
  (meaningful on rotation without translation);
- motion content above 15 Hz (vibration, tapping): RMS of the gyro and the accelerometer and
  the accelerometer's largest spike off its 0.5 s mean;
- rest detection on the still phases and in the movement: the share of time called rest by
  `attitude.AttitudeFilter` and inside the chunks the tracking filter's settings release
  (both use `kernels.rest.rest_sample`; the tracking filter's constants from `fusion.params.Params`).

    python -m benchmarks.imu_real [--data DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

from benchmarks.attitude_real import DATA_DIR, load_trial, trials

DEG = np.pi / 180.0


def still_phases(tr: dict, edge_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the still phase before the first movement sample and after the last one."""
    t, m = tr["t_s"], tr["movement"]
    idx = np.flatnonzero(m)
    before = (t > t[0] + 1.0) & (t < t[idx[0]] - edge_s)
    after = (t > t[idx[-1]] + edge_s) & (t < t[-1] - 1.0)
    return before, after


def bench_bias_change_sd_dps(tr: dict) -> float:
    """SD per axis of the bias change over the movement phase under the bench's gyro model."""
    from services.bench.scenario import GyroConfig

    c = GyroConfig()
    idx = np.flatnonzero(tr["movement"])
    sel = slice(idx[0], idx[-1] + 1)
    w = np.linalg.norm(tr["gyr"][sel], axis=1)
    q = c.bias_rw_static_dps_rts + c.bias_rw_motion_dps_rts_per_radps * w
    return float(np.sqrt(np.sum(q**2) / tr["rate_hz"]))


def gyro_lag_samples(tr: dict, max_shift: int = 6) -> int:
    """Shift s (samples) minimising |d(a/|a|)/dt + w[k - s] x a/|a|| on 5 Hz low-passed data:
    s > 0 means the gyroscope lags the accelerometer."""
    sos = butter(2, 5.0, fs=tr["rate_hz"], output="sos")
    acc = sosfiltfilt(sos, tr["acc"], axis=0)
    gyr = sosfiltfilt(sos, tr["gyr"], axis=0)
    u = acc / np.linalg.norm(acc, axis=1, keepdims=True)
    du = np.gradient(u, 1.0 / tr["rate_hz"], axis=0)
    shifts = np.arange(-max_shift, max_shift + 1)
    inner = slice(50, -50)
    cost = [np.mean(np.sum((du + np.cross(np.roll(gyr, -s, axis=0), u))[inner] ** 2, axis=1)) for s in shifts]
    return int(shifts[int(np.argmin(cost))])


def high_band(tr: dict, lo_hz: float = 15.0) -> dict[str, float]:
    """RMS above lo_hz in the movement phase (gyro deg/s, accel m/s^2) and the largest spike of
    the accelerometer off its 0.5 s moving mean (m/s^2)."""
    sos = butter(4, lo_hz, btype="high", fs=tr["rate_hz"], output="sos")
    m = tr["movement"]
    g = sosfiltfilt(sos, tr["gyr"], axis=0)[m] / DEG
    a = sosfiltfilt(sos, tr["acc"], axis=0)[m]
    n = int(0.5 * tr["rate_hz"])
    kern = np.ones(n) / n
    mean = np.column_stack([np.convolve(tr["acc"][:, k], kern, mode="same") for k in range(3)])
    spike = np.linalg.norm(tr["acc"] - mean, axis=1)[m]
    return {
        "gyr_rms_dps": float(np.sqrt(np.mean(np.sum(g**2, axis=1)))),
        "acc_rms_mps2": float(np.sqrt(np.mean(np.sum(a**2, axis=1)))),
        "acc_spike_mps2": float(spike.max()),
    }


def rest_attitude(tr: dict) -> np.ndarray:
    """Per-row rest flag of `attitude.AttitudeFilter`'s detector."""
    from services.fusion.attitude.filter import AttitudeFilter

    f = AttitudeFilter()
    out = np.zeros(tr["t_s"].size, bool)
    for i, (t, g, a) in enumerate(zip(tr["t_s"], tr["gyr"], tr["acc"], strict=True)):
        f.update(t, g, a)
        out[i] = f.rest
    return out


def rest_tracking(tr: dict) -> np.ndarray:
    """Per-row flag of the tracking filter's detector: rows inside a chunk it released as rest
    (a gyro sample, then an accelerometer sample, per row, as the filter feeds it)."""
    from services.fusion.eskf.kernels.rest import rest_init, rest_sample
    from services.fusion.eskf.params import Params

    p = Params()
    k = np.array(
        [
            p.rest_tau_ms * 1e-3,
            (p.rest_th_gyro_dps * DEG) ** 2,
            p.rest_th_accel_mps2**2,
            p.rest_min_ms * 1e-3,
            p.rest_chunk_ms * 1e-3,
            p.imu_gap_ms * 1e-3,
            (p.rest_agree_gyro_dps * DEG) ** 2,
            p.rest_agree_accel_mps2**2,
        ]
    )
    st = rest_init()
    t_s = tr["t_s"]
    out = np.zeros(t_s.size, bool)
    for i in range(t_s.size):
        # a released chunk is the one before the chunk that agreed with it
        if rest_sample(st, tr["gyr"][i], t_s[i], 0, k):
            out[(t_s >= t_s[i] - 2 * k[4]) & (t_s < t_s[i] - k[4])] = True
        rest_sample(st, tr["acc"][i], t_s[i], 1, k)
    return out


def one(path: Path) -> dict:
    tr = load_trial(path)
    before, after = still_phases(tr)
    still = before | after
    g_sd = tr["gyr"][before].std(axis=0) / DEG
    a_sd = tr["acc"][before].std(axis=0)
    bias_change = (tr["gyr"][after].mean(axis=0) - tr["gyr"][before].mean(axis=0)) / DEG
    moving = tr["movement"]
    ra, rt = rest_attitude(tr), rest_tracking(tr)
    return {
        "trial": path.stem,
        "gyr_density_dps_rthz": float(np.mean(g_sd) / np.sqrt(tr["rate_hz"])),
        "acc_sd_mps2": float(np.mean(a_sd)),
        "acc_tilt_sd_deg": float(np.degrees(np.mean(a_sd[:2]) / 9.81)),
        "acc_norm_mps2": float(np.linalg.norm(tr["acc"][before].mean(axis=0))),
        "bias_before_dps": tr["gyr"][before].mean(axis=0) / DEG,
        "bias_change_dps": bias_change,
        "bench_change_sd_dps": bench_bias_change_sd_dps(tr),
        "lag_samples": gyro_lag_samples(tr),
        **high_band(tr),
        "rest_still": (float(ra[still].mean()), float(rt[still].mean())),
        "rest_moving": (float(ra[moving].mean()), float(rt[moving].mean())),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.imu_real", description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DATA_DIR), help="folder of BROAD .mat trials")
    args = ap.parse_args(argv)
    files = trials(Path(args.data))
    if not files:
        print(f"imu_real: no .mat trials in {args.data}", file=sys.stderr)
        return 2
    from services.bench.scenario import AccelConfig, GyroConfig

    gc, ac = GyroConfig(), AccelConfig()
    print(
        f"bench: gyro {gc.noise_density_dps_rthz} deg/s/rtHz, bias SD {gc.bias_instability_dps} deg/s, "
        f"bias walk {gc.bias_rw_static_dps_rts} + {gc.bias_rw_motion_dps_rts_per_radps} |w| deg/s/rts; "
        f"accel {ac.noise_sd_mps2} m/s^2 per sample at {ac.rate_hz:g} Hz "
        f"({ac.noise_sd_mps2 / np.sqrt(ac.rate_hz):.4f} m/s^2/rtHz); gyro and accel latency "
        f"{gc.latency_ms} / {ac.latency_ms} ms"
    )
    for r in map(one, files):
        print(f"\n{r['trial']}")
        print(
            f"  at rest: gyro {r['gyr_density_dps_rthz']:.4f} deg/s/rtHz, accel {r['acc_sd_mps2']:.4f} m/s^2 "
            f"per sample ({r['acc_sd_mps2'] / np.sqrt(285.714):.4f} m/s^2/rtHz, tilt {r['acc_tilt_sd_deg']:.3f} deg), "
            f"|acc| {r['acc_norm_mps2']:.4f} m/s^2"
        )
        b, db = r["bias_before_dps"], r["bias_change_dps"]
        print(
            f"  gyro bias before [{b[0]:+.3f} {b[1]:+.3f} {b[2]:+.3f}] deg/s, change over the movement "
            f"[{db[0]:+.3f} {db[1]:+.3f} {db[2]:+.3f}] deg/s; the bench's model: SD {r['bench_change_sd_dps']:.3f}"
        )
        print(
            f"  gyro lag behind accel: {r['lag_samples']} samples; above 15 Hz in motion: gyro "
            f"{r['gyr_rms_dps']:.2f} deg/s, accel {r['acc_rms_mps2']:.3f} m/s^2 RMS, accel spike "
            f"{r['acc_spike_mps2']:.1f} m/s^2"
        )
        (sa, st), (ma, mt) = r["rest_still"], r["rest_moving"]
        print(
            f"  rest called (attitude / tracking filter): still phases {100 * sa:.0f} % / {100 * st:.0f} %, "
            f"movement {100 * ma:.1f} % / {100 * mt:.1f} %"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
