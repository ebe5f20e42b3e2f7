"""The translation and rotation protocols' accuracy (paper, Translation and Rotation Accuracy):
the static-trial filter's displacement and relative rotation between each trial's two
stationary windows against the robot's, with no alignment.

Translation: displacement error |d_est - d_true| per trial; RMSE with a bootstrap 95 % CI
(5000 resamples over trials, seeded), median and p95, per step and per axis; the scale is the
least-squares slope of |d_est| against |d_true|; steps of 1 and 2 mm are marked held out (the
paper fitted its constants on 5, 10 and 20 mm). Rotation: the rotation-angle error
|angle(R_rel_est)| - |angle(R_rel_true)|, the relative-rotation error angle(R_rel_est
R_rel_true^T), and the tip displacement error; repetitions 4-10 are marked held out.
The robot reference is read here only, as the ground truth of the evaluation.

    python -m study.static SESSION.mcap --json OUT.json [--calibration FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from study.evaluation import public
from study.static_trials import TrialEstimate, estimate_trials
from tiplog import mcap_io
from tiplog.calibration import Calibration, CalibrationError
from tiplog.calibration.fits.windows import mean_rotation
from tiplog.geometry import quat_to_rot, rotation_angle
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file

HELD_OUT_STEPS_MM = (1.0, 2.0)
HELD_OUT_REPS = range(4, 11)


def bootstrap_rmse_ci(err: np.ndarray, n: int = 5000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile interval of the RMSE of `err` over n resamples (seeded)."""
    e = np.asarray(err, float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(e), size=(n, len(e)))
    r = np.sqrt(np.mean(e[idx] ** 2, axis=1))
    return float(np.percentile(r, 2.5)), float(np.percentile(r, 97.5))


def summary(err: np.ndarray, seed: int = 0) -> dict[str, float]:
    """n, RMSE [bootstrap 95 % CI], median and p95 of per-trial errors."""
    e = np.asarray(err, float)
    lo, hi = bootstrap_rmse_ci(e, seed=seed)
    return {
        "n": int(len(e)),
        "rmse": float(np.sqrt(np.mean(e**2))),
        "ci95": [lo, hi],
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
    }


def scale(est: np.ndarray, true: np.ndarray) -> float:
    """Least-squares slope through the origin of |est| against |true|."""
    e, t = np.asarray(est, float), np.asarray(true, float)
    return float(np.sum(e * t) / np.sum(t * t))


def robot_windows(path: str | Path, estimates: list[TrialEstimate], tail: float = 0.9) -> list[tuple]:
    """Per trial the robot's mean (tip, R) in the last `tail` of its pre and post windows."""
    t, p, q = [], [], []
    for rec in mcap_io.read_messages(path, ["bench/robot"]):
        m = rec.message
        t.append(m.header.stamp_ns)
        p.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        o = m.tool_pose.orientation
        q.append((o.x, o.y, o.z, o.w))
    if not t:
        raise UserError(f"{path}: no robot reference (bench/robot) to evaluate against")
    t_a, p_a, R_a = np.asarray(t), np.asarray(p), quat_to_rot(np.asarray(q))
    out = []
    for e in estimates:
        pair = []
        for lo, hi in (e.windows.pre_ns, e.windows.post_ns):
            sel = (t_a >= hi - tail * (hi - lo)) & (t_a <= hi)
            pair.append((p_a[sel].mean(0), mean_rotation(R_a[sel])))
        out.append(tuple(pair))
    return out


def _reps(metadata: dict[str, dict[str, str]]) -> dict[int, int]:
    try:
        return {int(tr["index"]): int(tr.get("rep", 0)) for tr in json.loads(metadata["trials"]["json"])}
    except (KeyError, ValueError, TypeError):
        return {}


def evaluate_static(path: str | Path, calibration: Calibration | None = None) -> dict[str, Any]:
    """Metrics of a translation or rotation session (see the module docstring)."""
    try:
        est, counts = estimate_trials(path, calibration)
    except ValueError as e:
        raise UserError(str(e)) from None
    truth = robot_windows(path, est)
    kinds = {e.windows.kind for e in est}
    d_est = np.array([e.displacement_base_m for e in est]) * 1e3
    d_true = np.array([(b[0] - a[0]) for a, b in truth]) * 1e3
    tip_err = np.linalg.norm(d_est - d_true, axis=1)
    out: dict[str, Any] = {"session": str(path), "trials": len(est), "filter_updates": counts}
    axes = np.array([e.windows.axis for e in est])
    # per-trial errors for plots (private: not written to JSON)
    out["_errors"] = {"tip_mm": tip_err, "axis": axes, "magnitude": np.array([e.windows.magnitude for e in est])}
    if "translation" in kinds:
        steps = np.abs(np.array([e.windows.magnitude for e in est]))  # +- along an axis pooled
        per_step = {
            f"{s:g}": {**summary(tip_err[steps == s]), "held_out": bool(s in HELD_OUT_STEPS_MM)}
            for s in np.unique(steps)
        }
        out["translation"] = {
            "rmse_mm": float(np.sqrt(np.mean(tip_err**2))),
            "scale": scale(np.linalg.norm(d_est, axis=1), np.linalg.norm(d_true, axis=1)),
            "all": summary(tip_err),
            "per_step": per_step,
            "per_axis": {a: summary(tip_err[axes == a]) for a in np.unique(axes)},
        }
    if "rotation" in kinds:
        R_true = np.array([b[1] @ a[1].T for a, b in truth])
        R_est = np.array([e.R_rel for e in est])
        ang = np.degrees(rotation_angle(R_est) - rotation_angle(R_true))
        rel = np.degrees(rotation_angle(np.einsum("nij,nkj->nik", R_est, R_true)))
        reps = _reps(mcap_io.read_metadata(path))
        held = np.array([reps.get(e.windows.index, 0) in HELD_OUT_REPS for e in est])
        out["_errors"] |= {"relrot_deg": rel, "angle_deg": ang}
        out["rotation"] = {
            "angle_rmse_deg": float(np.sqrt(np.mean(ang**2))),
            "relrot_rmse_deg": float(np.sqrt(np.mean(rel**2))),
            "tip_rmse_mm": float(np.sqrt(np.mean(tip_err**2))),
            "gain": scale(np.degrees(rotation_angle(R_est)), np.degrees(rotation_angle(R_true))),
            "relrot": summary(rel),
            "relrot_held_out": summary(rel[held]) if held.any() else None,
            "per_axis": {
                a: {"angle": summary(np.abs(ang[axes == a])), "relrot": summary(rel[axes == a])}
                for a in np.unique(axes)
            },
        }
    return out


def markdown(res: dict[str, Any]) -> str:
    """The paper's per-step translation table and the rotation summary."""
    lines = []
    if "translation" in res:
        t = res["translation"]
        lines += ["| Step (mm) | n | RMSE [95% CI] (mm) | Median | 95th pct. |", "| --- | --- | --- | --- | --- |"]
        for s, r in t["per_step"].items():
            mark = "†" if r["held_out"] else ""
            lines.append(
                f"| {s}{mark} | {r['n']} | {r['rmse']:.2f} [{r['ci95'][0]:.2f}, {r['ci95'][1]:.2f}] | {r['median']:.2f} | {r['p95']:.2f} |"
            )
        a = t["all"]
        lines.append(
            f"| All | {a['n']} | {a['rmse']:.2f} [{a['ci95'][0]:.2f}, {a['ci95'][1]:.2f}] | {a['median']:.2f} | {a['p95']:.2f} |"
        )
        lines.append(f"\nScale {t['scale']:.3f}. † held out of calibration in the paper.")
    if "rotation" in res:
        r = res["rotation"]
        lines += [
            "| Angle (deg) | Rel. rot. (deg) | Tip (mm) | Gain |",
            "| --- | --- | --- | --- |",
            f"| {r['angle_rmse_deg']:.3f} | {r['relrot_rmse_deg']:.3f} | {r['tip_rmse_mm']:.2f} | {r['gain']:.4f} |",
        ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m study.static", description=__doc__)
    p.add_argument("session", help="translation- or rotation-protocol session with bench/robot (MCAP)")
    p.add_argument("--json", required=True, help="result file to write (JSON)")
    p.add_argument("--calibration", help="calibration YAML (default: the session's own)")
    p.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    try:
        src = input_mcap(args.session)
        output_file(args.json, args.force)
        cal = None
        if args.calibration:
            try:
                cal = Calibration.load_yaml(input_file(args.calibration, "calibration file"))
            except CalibrationError as e:
                raise UserError(str(e)) from None
        res = evaluate_static(src, cal)
        with atomic_output(args.json, args.force) as tmp:
            tmp.write_text(json.dumps(public(res), indent=1) + "\n")
    except UserError as e:
        sys.stderr.write(f"evaluate_static: {e}\n")
        return 2
    sys.stdout.write(markdown(res) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
