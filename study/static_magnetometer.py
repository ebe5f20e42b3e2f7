"""The magnetometer study on bench recordings (paper, Preliminary Study): rotation angles from
accelerometer and magnetometer alone (TRIAD) against the robot on the rotation protocol, the
field's angle to gravity across the rests of each trial, and nine-axis heading drift (against
accelerometer tilt drift) in the static holds. Reads the robot reference only to know the true
rotation angle and where the rests are.

    python -m study.static_magnetometer ROTATION.mcap [STATIC.mcap] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from tiplog.calibration.data import CalibrationData, load
from tiplog.calibration.fits.magnetometer import field_gravity_angle_deg, hold_drift_deg, triad_rotation_angle_deg
from tiplog.calibration.fits.windows import mean_rotation
from tiplog.geometry import rotation_angle
from tiplog.userio import UserError, atomic_output, output_file

TRIM_NS = 300_000_000
EDGE_NS = 2_000_000_000


def _rests(d: CalibrationData, phases: tuple[str, ...]) -> dict[tuple[int, str], tuple[int, int]]:
    """(trial, phase) -> (t0, t1) of the robot's rests, trimmed."""
    out = {}
    for tr in np.unique(d.robot_trial[d.robot_trial >= 0]):
        for ph in phases:
            sel = (d.robot_trial == tr) & (d.robot_phase == ph)
            if sel.sum() > 10:
                t = d.robot_t_ns[sel]
                out[(int(tr), ph)] = (int(t[0]) + TRIM_NS, int(t[-1]) - TRIM_NS)
    return out


def _mean(t: np.ndarray, x: np.ndarray, t0: int, t1: int, lat_ns: int) -> np.ndarray:
    i0, i1 = np.searchsorted(t - lat_ns, [t0, t1])
    return x[i0:i1].mean(0) if i1 > i0 else np.full(x.shape[1], np.nan)


def rotation_study(d: CalibrationData) -> dict[str, Any]:
    lat = d.prior.latency_ms if d.prior else {}
    la, lm = int(lat.get("accel", 0) * 1e6), int(lat.get("mag", 0) * 1e6)
    rests = _rests(d, ("pre", "post"))
    trials = sorted({k[0] for k in rests if (k[0], "pre") in rests and (k[0], "post") in rests})
    if not trials:
        raise UserError(f"{d.source}: no trials with pre and post rests (record the rotation protocol)")
    a = np.array([[_mean(d.accel_t_ns, d.accel_mps2, *rests[(k, ph)], la) for ph in ("pre", "post")] for k in trials])
    m = np.array([[_mean(d.mag_t_ns, d.mag_ut, *rests[(k, ph)], lm) for ph in ("pre", "post")] for k in trials])
    R = []
    for k in trials:
        pair = []
        for ph in ("pre", "post"):
            t0, t1 = rests[(k, ph)]
            sel = (d.robot_t_ns >= t0) & (d.robot_t_ns < t1)
            pair.append(mean_rotation(d.R_base_tool[sel]) if sel.any() else np.eye(3))
        R.append(pair)
    R = np.array(R)
    ok = np.all(np.isfinite(a), axis=(1, 2)) & np.all(np.isfinite(m), axis=(1, 2))  # a rest cut short
    if not ok.any():
        raise UserError(f"{d.source}: no trial has accelerometer and magnetometer samples in both rests")
    a, m, R, trials = a[ok], m[ok], R[ok], [k for k, o in zip(trials, ok, strict=True) if o]
    true_deg = np.degrees(rotation_angle(np.einsum("nij,nkj->nik", R[:, 1], R[:, 0])))
    triad_deg = triad_rotation_angle_deg(a[:, 0], m[:, 0], a[:, 1], m[:, 1])
    err = triad_deg - true_deg
    fg = field_gravity_angle_deg(a, m)
    change = np.abs(fg[:, 1] - fg[:, 0])
    return {
        "trials": len(trials),
        "triad_angle_rmse_deg": float(np.sqrt(np.mean(err**2))),
        "triad_angle_median_abs_deg": float(np.median(np.abs(err))),
        "field_gravity_angle_deg": {"mean": float(fg.mean()), "min": float(fg.min()), "max": float(fg.max())},
        "field_gravity_change_in_trial_deg": {"median": float(np.median(change)), "max": float(change.max())},
    }


def static_study(d: CalibrationData) -> dict[str, Any]:
    lat = d.prior.latency_ms if d.prior else {}
    la, lm = int(lat.get("accel", 0) * 1e6), int(lat.get("mag", 0) * 1e6)
    rests = _rests(d, ("hold", "post"))
    if not rests:
        raise UserError(f"{d.source}: no static holds (record the static protocol)")
    heading, tilt, dur = [], [], []
    for t0, t1 in rests.values():
        if t1 - t0 < 3 * EDGE_NS:
            continue
        a0, a1 = (
            _mean(d.accel_t_ns, d.accel_mps2, t0, t0 + EDGE_NS, la),
            _mean(d.accel_t_ns, d.accel_mps2, t1 - EDGE_NS, t1, la),
        )
        m0, m1 = _mean(d.mag_t_ns, d.mag_ut, t0, t0 + EDGE_NS, lm), _mean(d.mag_t_ns, d.mag_ut, t1 - EDGE_NS, t1, lm)
        h, ti = hold_drift_deg(a0, m0, a1, m1)
        heading.append(h)
        tilt.append(ti)
        dur.append((t1 - t0) * 1e-9)
    field = np.linalg.norm(d.mag_ut, axis=1)
    return {
        "holds": len(heading),
        "hold_s": [round(float(np.min(dur)), 1), round(float(np.max(dur)), 1)],
        "heading_drift_deg": {"median": float(np.median(heading)), "max": float(np.max(heading))},
        "accel_tilt_drift_deg": {"median": float(np.median(tilt)), "max": float(np.max(tilt))},
        "mean_field_ut": float(field.mean()),
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m study.static_magnetometer", description=__doc__)
    p.add_argument("rotation", help="rotation-protocol recording (MCAP)")
    p.add_argument("static", nargs="?", help="static-protocol recording (MCAP)")
    p.add_argument("--json", help="write the numbers here")
    p.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    try:
        if args.json:
            output_file(args.json, args.force)
        out: dict[str, Any] = {"rotation": rotation_study(load(args.rotation))}
        if args.static:
            out["static"] = static_study(load(args.static))
        text = json.dumps(out, indent=1)
        if args.json:
            with atomic_output(args.json, args.force) as tmp:
                tmp.write_text(text + "\n")
    except UserError as e:
        sys.stderr.write(f"magnetometer study: {e}\n")
        return 2
    sys.stdout.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
