"""`tiplog fusion attitude` beside VQF (6-D) on bench recordings with motion.

For each scenario and seed: generate a bench session, export device/gyro and device/accel to
the command's CSV format (accelerometer linearly resampled to the gyro stamps), run the
command on it and the `vqf` package's causal 6-D filter on the same CSV, and compare the
inclination of each (the angle between the estimated and the true up direction in IMU axes)
with the bench's truth: bench/robot's tool orientation through the true IMU mounting
R_tool_imu (allowed here, in the benchmark, never in the estimator), at the gyro's event time
(arrival stamp minus the true gyro latency). The first `--settle` seconds are left out.

    python -m benchmarks.attitude_vqf [--scenarios sweeps teleop] [--seeds 1 2 3] [--duration S]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from tiplog import mcap_io


def export_csv(session: Path, out_csv: Path) -> int:
    """device/gyro + device/accel of `session` -> CSV (t_s, gyr_*, acc_*) on the gyro stamps."""
    g_t, g, a_t, a = [], [], [], []
    for r in mcap_io.read_messages(session, ["device/gyro", "device/accel"]):
        h = r.message.header
        if r.topic == "device/gyro":
            v = r.message.rate_radps
            g_t.append(h.stamp_ns)
            g.append((v.x, v.y, v.z))
        else:
            v = r.message.specific_force_mps2
            a_t.append(h.stamp_ns)
            a.append((v.x, v.y, v.z))
    gt = np.asarray(g_t, np.int64)
    at = np.asarray(a_t, np.int64)
    order = np.argsort(gt, kind="stable")
    gt, g = gt[order], np.asarray(g)[order]
    a = np.asarray(a)[np.argsort(at, kind="stable")]
    at = np.sort(at)
    keep = (gt >= at[0]) & (gt <= at[-1])
    gt, g = gt[keep], g[keep]
    acc = np.stack([np.interp(gt, at, a[:, k]) for k in range(3)], -1)
    with open(out_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"])
        for t, gi, ai in zip(gt, g, acc, strict=True):
            w.writerow([f"{t * 1e-9:.9f}", *(f"{x:.9g}" for x in gi), *(f"{x:.9g}" for x in ai)])
    return len(gt)


def truth_up_imu(session: Path, t_s: np.ndarray) -> np.ndarray:
    """True up direction (base +z) in IMU axes at event times t_s (N,) -> (N, 3)."""
    md = mcap_io.read_metadata(session)
    truth = json.loads(md["calibration_truth"]["json"])
    R_tool_imu = np.asarray(truth["R_tool_imu"])
    lat_s = float(truth["latency_ms"]["gyro"]) * 1e-3
    ts, qs = [], []
    for r in mcap_io.read_messages(session, ["bench/robot"]):
        o = r.message.tool_pose.orientation
        ts.append(r.message.header.stamp_ns * 1e-9)
        qs.append((o.x, o.y, o.z, o.w))
    slerp = Slerp(np.asarray(ts), Rotation.from_quat(np.asarray(qs)))
    te = np.clip(t_s - lat_s, ts[0], ts[-1])
    R_base_imu = slerp(te).as_matrix() @ R_tool_imu
    return R_base_imu[:, 2, :]  # rows of R^T e_z: the base z axis in imu coordinates


def inclination_error_deg(q_wxyz: np.ndarray, up_imu: np.ndarray) -> np.ndarray:
    """Angle [deg] between each estimate's up direction in sensor axes and the truth's."""
    R = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]).as_matrix()
    up_est = R[:, 2, :]
    c = np.clip((up_est * up_imu).sum(-1) / np.linalg.norm(up_est, axis=-1), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def stats(err: np.ndarray) -> dict[str, float]:
    return {
        "rms_deg": float(np.sqrt(np.mean(err**2))),
        "median_deg": float(np.median(err)),
        "p95_deg": float(np.percentile(err, 95)),
        "max_deg": float(err.max()),
    }


def run_vqf(t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray, tau_acc_s: float = 3.0) -> np.ndarray:
    from vqf import VQF  # benchmark-only reference

    dt = float(np.median(np.diff(t_s)))
    out = VQF(dt, tauAcc=tau_acc_s).updateBatch(np.ascontiguousarray(gyr), np.ascontiguousarray(acc))
    return out["quat6D"]


def one(scenario: str, seed: int, duration: float | None, settle_s: float, work: Path, tau_acc_s: float) -> dict:
    from services.fusion.attitude.cli import read_csv
    from tiplog.cli import main as tiplog_main

    session = work / f"{scenario}_{seed}.mcap"
    if not session.exists():
        args = ["sim", "generate", "--scenario", scenario, "--seed", str(seed), "--out", str(session), "--quiet"]
        if duration:
            args += ["--duration", str(duration)]
        if tiplog_main(args) != 0:
            raise RuntimeError(f"generating {scenario} seed {seed} failed")
    in_csv, out_csv = work / f"{scenario}_{seed}.csv", work / f"{scenario}_{seed}_att.csv"
    n = export_csv(session, in_csv)
    t0 = time.perf_counter()
    if tiplog_main(["fusion", "attitude", str(in_csv), str(out_csv), "--force", "--tau-acc", str(tau_acc_s)]) != 0:
        raise RuntimeError("tiplog fusion attitude failed")
    ours_s = time.perf_counter() - t0
    t_s, gyr, acc = read_csv(in_csv)
    ours = np.loadtxt(out_csv, delimiter=",", skiprows=1)[:, 1:]
    t0 = time.perf_counter()
    ref = run_vqf(t_s, gyr, acc, tau_acc_s)
    vqf_s = time.perf_counter() - t0
    up = truth_up_imu(session, t_s)
    keep = t_s >= t_s[0] + settle_s
    return {
        "scenario": scenario,
        "seed": seed,
        "tau_acc_s": tau_acc_s,
        "rows": n,
        "seconds": float(t_s[-1] - t_s[0]),
        "ours": stats(inclination_error_deg(ours, up)[keep]) | {"wall_s": ours_s},
        "vqf": stats(inclination_error_deg(ref, up)[keep]) | {"wall_s": vqf_s},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.attitude_vqf", description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["sweeps", "teleop"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--duration", type=float, help="cut each session to this many seconds")
    ap.add_argument("--tau-acc", type=float, default=3.0, help="accelerometer time constant of both filters [s]")
    ap.add_argument("--settle", type=float, default=5.0, help="seconds left out at the start")
    ap.add_argument("--work", help="folder for sessions and CSVs (default: a temporary one)")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = [
            one(s, seed, args.duration, args.settle, work, args.tau_acc) for s in args.scenarios for seed in args.seeds
        ]
    print(f"{'scenario':8} {'seed':>4} {'s':>6} | {'ours rms/med/p95 deg':>22} | {'vqf rms/med/p95 deg':>22}")
    for r in rows:
        o, v = r["ours"], r["vqf"]
        print(
            f"{r['scenario']:8} {r['seed']:>4} {r['seconds']:6.1f} | "
            f"{o['rms_deg']:6.3f} {o['median_deg']:6.3f} {o['p95_deg']:6.3f} ({o['wall_s']:.2f} s) | "
            f"{v['rms_deg']:6.3f} {v['median_deg']:6.3f} {v['p95_deg']:6.3f}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
