"""Static stability (paper, Static Stability and its table of static noise): on the static
protocol (holds of 30 s at four poses and a soak), per hold the SD of the accelerometer's tilt
and of the raw ToF range within the hold and the robot tip's own motion (the paper's table,
per pose mean +- SD over its holds), and the tracking filter's state in each hold: jitter (RMS
about the hold's mean), drift (last 2 s against the first 2 s) and offset from the robot.

The filter reads only device and vision topics and the calibration; the robot reference and
the trial windows are read here for scoring only. Hold windows are the trials' `post` windows
(milliseconds on the session clock), trimmed by 0.3 s at both ends.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from services.fusion.eskf.params import Params
from services.fusion.offline.inputs import iter_inputs
from study.ablation import SUBSETS, run_variant
from study.evaluation import EvaluationError, interp_columns, load_truth
from tiplog.calibration import Calibration
from tiplog.calibration import data as calibrate_data
from tiplog.mcap_io import read_metadata

TRIM_NS = 300_000_000
EDGE_NS = 2_000_000_000
HOLD_KINDS = ("hold", "soak")


def hold_windows(trials: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """[{index, kind, pose, t0_ns, t1_ns}] of the holds and the soak, trimmed; holds shorter
    than three edge windows (6 s) are left out."""
    out = []
    for tr in trials:
        if tr.get("kind") not in HOLD_KINDS:
            continue
        t0, t1 = int(tr["post_start"]) * 1_000_000 + TRIM_NS, int(tr["post_end"]) * 1_000_000 - TRIM_NS
        if t1 - t0 >= 3 * EDGE_NS:
            out.append(
                {"index": int(tr["index"]), "kind": tr["kind"], "pose": str(tr["axis"]), "t0_ns": t0, "t1_ns": t1}
            )
    return out


def _tilt_sd_deg(a: np.ndarray) -> float:
    """SD of the angle between each accelerometer sample (n, 3) and their mean direction."""
    u = a / np.linalg.norm(a, axis=1, keepdims=True)
    m = u.mean(0)
    m /= np.linalg.norm(m)
    ang = np.degrees(np.arccos(np.clip(u @ m, -1.0, 1.0)))
    return float(np.sqrt(np.mean(ang**2)))


def _tilt_change_deg(a0: np.ndarray, a1: np.ndarray) -> float:
    u0, u1 = a0.mean(0), a1.mean(0)
    c = u0 @ u1 / (np.linalg.norm(u0) * np.linalg.norm(u1))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _in(t: np.ndarray, t0: int, t1: int) -> np.ndarray:
    return (t >= t0) & (t < t1)


def _edges(t: np.ndarray, x: np.ndarray, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray]:
    return x[_in(t, t0, t0 + EDGE_NS)], x[_in(t, t1 - EDGE_NS, t1)]


def evaluate_holds(session: str | Path, calibration: Calibration | None = None) -> dict[str, Any]:
    """Per-hold raw-stream noise, the filter's stability and the per-pose table (see module)."""
    truth = load_truth(session)
    holds = hold_windows(truth.trials)
    if not holds:
        raise EvaluationError(f"{session}: no static holds of 6 s or more (record the static protocol)")
    d = calibrate_data.load(session)
    calib = calibration or Calibration.from_mcap_metadata(read_metadata(session), where=str(session))
    est, diag, _cpu = run_variant(iter_inputs(Path(session), {}), calib, Params(), SUBSETS["full"])
    rows = []
    for h in holds:
        t0, t1 = h["t0_ns"], h["t1_ns"]
        acc = d.accel_mps2[_in(d.accel_t_ns, t0, t1)]
        tof_sel = _in(d.tof_t_ns, t0, t1) & d.tof_valid
        tip = truth.tip_base_m[_in(truth.t_ns, t0, t1)]
        e_sel = _in(est.t_ns, t0, t1)
        p = est.tip_base_m[e_sel]
        row = dict(h, duration_s=round((t1 - t0) * 1e-9, 1))
        row["accel_tilt_sd_deg"] = _tilt_sd_deg(acc) if len(acc) > 2 else float("nan")
        row["accel_tilt_drift_deg"] = _tilt_change_deg(*_edges(d.accel_t_ns, d.accel_mps2, t0, t1))
        row["tof_raw_sd_mm"] = float(np.std(d.tof_raw_mm[tof_sel])) if tof_sel.sum() > 2 else float("nan")
        row["robot_tip_sd_mm"] = float(np.sqrt(np.sum(np.var(tip, axis=0))) * 1e3) if len(tip) > 2 else float("nan")
        if len(p) > 2:
            row["fusion_jitter_mm"] = float(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, 1))) * 1e3)
            a, b = _edges(est.t_ns, est.tip_base_m, t0, t1)
            row["fusion_drift_mm"] = float(np.linalg.norm(b.mean(0) - a.mean(0)) * 1e3)
            p_true = interp_columns(est.t_ns[e_sel], truth.t_ns, truth.tip_base_m)
            row["fusion_offset_mm"] = float(np.linalg.norm((p - p_true).mean(0)) * 1e3)
        else:
            row.update(fusion_jitter_mm=float("nan"), fusion_drift_mm=float("nan"), fusion_offset_mm=float("nan"))
        rows.append(row)
    per_pose: dict[str, Any] = {}
    keys = ("accel_tilt_sd_deg", "tof_raw_sd_mm", "robot_tip_sd_mm", "fusion_jitter_mm", "fusion_drift_mm")
    for pose in sorted({r["pose"] for r in rows if r["kind"] == "hold"}):
        sel = [r for r in rows if r["kind"] == "hold" and r["pose"] == pose]
        per_pose[pose] = {"holds": len(sel)} | {
            k: [float(np.nanmean([r[k] for r in sel])), float(np.nanstd([r[k] for r in sel]))] for k in keys
        }
    soak = next((r for r in rows if r["kind"] == "soak"), None)
    return {
        "holds": rows,
        "per_pose": per_pose,
        "soak": soak,
        "max_fusion_drift_mm": float(np.nanmax([r["fusion_drift_mm"] for r in rows])),
        "max_fusion_jitter_mm": float(np.nanmax([r["fusion_jitter_mm"] for r in rows])),
        "filter_resets": int(diag.get("resets", 0)),
    }


def markdown(res: dict[str, Any]) -> str:
    """The paper's static-noise table (per pose, mean +- SD over holds) with the filter's
    stability beside it, and the soak's line."""
    lines = [
        "| Pose | holds | Accel. tilt (deg) | Raw ToF (mm) | Robot tip (mm) | Fusion jitter (mm) | Fusion drift (mm) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for pose, r in res["per_pose"].items():
        cells = " | ".join(
            f"{r[k][0]:.{n}f}±{r[k][1]:.{n}f}"
            for k, n in (
                ("accel_tilt_sd_deg", 2),
                ("tof_raw_sd_mm", 2),
                ("robot_tip_sd_mm", 3),
                ("fusion_jitter_mm", 3),
                ("fusion_drift_mm", 3),
            )
        )
        lines.append(f"| {pose} | {r['holds']} | {cells} |")
    s = res.get("soak")
    if s:
        lines.append(
            f"\nSoak ({s['duration_s']:.0f} s at {s['pose']}): accelerometer tilt drift {s['accel_tilt_drift_deg']:.3f} deg, "
            f"fusion drift {s['fusion_drift_mm']:.3f} mm, jitter {s['fusion_jitter_mm']:.3f} mm."
        )
    return "\n".join(lines)
