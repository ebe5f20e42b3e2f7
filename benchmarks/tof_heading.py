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

from services.bench.report.data import load, truth_p, truth_R
from study.evaluation import EvaluationError, block_windows
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError

TOF_VALID = 1
STEP_DEG = 0.1
STEP_M = 1e-3


def analyse(session: Path) -> list[dict]:
    if "calibration_truth" not in read_metadata(session):
        raise EvaluationError(f"{session}: not a bench session (no calibration_truth)")
    s = load(session)  # the bench report's reader: truth constants, robot poses, sensor arrays
    const, tof = s.truth, s.streams["tof"]
    t = tof["t"] - int(round(const.latency_ms.get("tof", 0.0) * 1e6))  # event time
    ok = (tof["s"] == TOF_VALID) & (t >= s.robot_t[0]) & (t <= s.robot_t[-1])
    t, rng = t[ok], tof["v"][ok] * 1e-3
    R, p, rcm = truth_R(s, t), truth_p(s, t), const.rcm_base_m
    rho = const.tof_range_m(R, p)
    Rz = Rotation.from_euler("z", STEP_DEG, degrees=True).as_matrix()
    d_heading = (const.tof_range_m(Rz @ R, rcm + (p - rcm) @ Rz.T) - rho) / STEP_DEG * 1e3  # mm/deg
    d_depth = (const.tof_range_m(R, p + STEP_M * R[:, :, 2]) - rho) / STEP_M  # mm/mm
    err = (rng - rho) * 1e3
    out = []
    for name, a, b in block_windows(s.trials):
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
