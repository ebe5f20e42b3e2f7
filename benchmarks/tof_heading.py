"""How much a bench session's ToF ranges say about the heading, and where they would put it.

Without vision only the ToF sees the heading (the turn about the vertical through the RCM, to
which gravity, the gyro and the RCM are blind). For each block of a session this takes the raw
ranges (valid ones, at their event time: arrival stamp minus the true ToF latency) and, at the
true pose (bench/robot), the true ray-plane model (the session's `calibration_truth`: allowed
here, in the benchmark, never in an estimator):

- the range's error against that model (RMS and mean, mm): the bench's white noise, pose-locked
  error and slow drift;
- the range's sensitivity to the heading (mm per degree) and to the depth along the shaft
  (mm per mm), mean and SD over the block: where their ratio hardly varies, the range pins
  only a combination of the two;
- the heading and depth offsets that a least-squares fit of that error gives with the range
  offset held (as the tracking filter holds b_rho without vision): where the ToF alone would
  put them.

    python -m benchmarks.tof_heading SESSION.mcap [SESSION.mcap ...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from services.bench.sensors.calibration import BenchConstants
from services.fusion.evaluation import EvaluationError, block_windows, load_truth
from tiplog.mcap_io import read_messages, read_metadata
from tiplog.userio import UserError

TOF_VALID = 1
STEP_DEG = 0.1
STEP_M = 1e-3


def _tool_orientation(session: Path) -> tuple[np.ndarray, Rotation]:
    t, q = [], []
    for rec in read_messages(session, ["bench/robot"]):
        o = rec.message.tool_pose.orientation
        t.append(rec.message.header.stamp_ns)
        q.append((o.x, o.y, o.z, o.w))
    return np.asarray(t, np.int64), Rotation.from_quat(q)


def _ranges(session: Path, latency_ns: int) -> tuple[np.ndarray, np.ndarray]:
    t, r = [], []
    for rec in read_messages(session, ["device/tof"]):
        m = rec.message
        if m.status == TOF_VALID:
            t.append(m.header.stamp_ns - latency_ns)
            r.append(m.range_raw_mm * 1e-3)
    return np.asarray(t, np.int64), np.asarray(r)


def analyse(session: Path) -> list[dict]:
    md = read_metadata(session)
    if "calibration_truth" not in md:
        raise EvaluationError(f"{session}: not a bench session (no calibration_truth)")
    const = BenchConstants.from_dict(json.loads(md["calibration_truth"]["json"]))
    truth = load_truth(session)
    t_rot, rot = _tool_orientation(session)
    t, rng = _ranges(session, int(round(const.latency_ms.get("tof", 0.0) * 1e6)))
    inside = (t >= max(t_rot[0], truth.t_ns[0])) & (t <= min(t_rot[-1], truth.t_ns[-1]))
    t, rng = t[inside], rng[inside]
    # the orientation at the range's time: the nearest robot sample (1 kHz)
    j = np.clip(np.searchsorted(t_rot, t), 1, len(t_rot) - 1)
    j -= (t - t_rot[j - 1]) < (t_rot[j] - t)
    R = rot[j].as_matrix()
    p = np.stack([np.interp(t, truth.t_ns, truth.tip_base_m[:, k]) for k in range(3)], 1)
    rcm = np.stack([np.interp(t, truth.t_ns, truth.rcm_base_m[:, k]) for k in range(3)], 1)
    rho = const.tof_range_m(R, p)
    Rz = Rotation.from_euler("z", STEP_DEG, degrees=True).as_matrix()
    d_heading = (const.tof_range_m(Rz @ R, rcm + (p - rcm) @ Rz.T) - rho) / STEP_DEG * 1e3  # mm/deg
    d_depth = (const.tof_range_m(R, p + STEP_M * R[:, :, 2]) - rho) / STEP_M  # mm/mm
    err = (rng - rho) * 1e3
    out = []
    for name, a, b in block_windows(truth.trials):
        k = (t >= a) & (t < b) & np.isfinite(rho) & np.isfinite(d_heading) & np.isfinite(d_depth)
        if k.sum() < 10:
            continue
        A = np.stack([d_heading[k], d_depth[k]], 1)
        x, *_ = np.linalg.lstsq(A, err[k], rcond=None)
        out.append(
            {
                "session": session.name,
                "block": name,
                "ranges": int(k.sum()),
                "error_rms_mm": float(np.sqrt(np.mean(err[k] ** 2))),
                "error_mean_mm": float(np.mean(err[k])),
                "heading_mm_per_deg": [float(np.mean(d_heading[k])), float(np.std(d_heading[k]))],
                "depth_mm_per_mm": [float(np.mean(d_depth[k])), float(np.std(d_depth[k]))],
                "fit_heading_deg": float(x[0]),
                "fit_depth_mm": float(x[1]),
            }
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.tof_heading", description=__doc__.splitlines()[0])
    ap.add_argument("sessions", nargs="+", type=Path, help="bench sessions (MCAP) with continuous blocks")
    ap.add_argument("--json", type=Path, help="write the rows to this file")
    a = ap.parse_args(argv)
    rows = []
    for s in a.sessions:
        try:
            rows += analyse(s)
        except (OSError, UserError, EvaluationError, KeyError, ValueError) as e:
            print(f"tof_heading: {s}: {e}", file=sys.stderr)
            return 2
    print(
        "session / block: ranges | error RMS, mean (mm) | heading mm/deg mean, SD | depth mm/mm mean, SD | fit heading (deg), depth (mm)"
    )
    for r in rows:
        h, d = r["heading_mm_per_deg"], r["depth_mm_per_mm"]
        print(
            f"{r['session']} / {r['block']}: {r['ranges']} | {r['error_rms_mm']:.2f}, {r['error_mean_mm']:.2f} | "
            f"{h[0]:.2f}, {h[1]:.3f} | {d[0]:.2f}, {d[1]:.3f} | {r['fit_heading_deg']:.1f}, {r['fit_depth_mm']:.1f}"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
