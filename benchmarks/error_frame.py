"""Where the tracking filter's tip error lies: per block, in the tool's frame and along the camera's line of sight.

For each continuous block of a bench session (scored as `tiplog evaluate` does: first 20 %
left out) this runs the filter over the recording and, against the bench's truth (here, in
the benchmark, never in an estimator), reports the tip error's mean and SD along the tool's
axes (x and y across the shaft, z along it) and along the camera's optical axis (the line of
sight, which vision does not see the tip along), and how much of the error along the shaft
changes within 0.5 s and 2 s (the SD left after averaging over that long).

`--swap FIELD,...` puts the bench's true value of calibration fields (from the session's
`calibration_truth`: R_tool_imu, T_base_camera, p_imu_tool_m, rcm_base_m, junction_proximal_m,
tof, latency, intrinsics) in place of the calibration's, to see which one an offset comes from.
That is analysis only: the filter itself refuses a record marked evaluation-only.

    python -m benchmarks.error_frame SESSION.mcap [--calibration FILE] [--params FILE]
        [--sensors imu,tof,vision] [--swap FIELD,...] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from services.bench.report.data import load, truth_p, truth_R
from services.fusion.eskf.params import Params
from services.fusion.offline.inputs import iter_inputs
from services.fusion.params_file import load_params
from study.ablation import run_states
from study.evaluation import EvaluationError, block_windows
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError

SWAPS = (
    "R_tool_imu", "T_base_camera", "p_imu_tool_m", "rcm_base_m", "junction_proximal_m", "tof", "latency", "intrinsics",
)  # fmt: skip
_TOF = ("tof_origin_tool_m", "tof_beam_tool", "tof_plane_normal_base", "tof_plane_h_m")
SMOOTH_S = (0.5, 2.0)


def check_swaps(fields: list[str]) -> None:
    """ValueError naming the first field that is not one of SWAPS."""
    for f in fields:
        if f not in SWAPS:
            raise ValueError(f"--swap: unknown field {f!r}; choose from {', '.join(SWAPS)}")


def swapped(calib: Calibration, truth, fields: list[str]) -> Calibration:
    """`calib` with the named fields (SWAPS) taken from the bench's true constants."""
    check_swaps(fields)
    rep: dict = {}
    for f in fields:
        if f == "tof":
            rep.update({k: getattr(truth, k) for k in _TOF})
        elif f == "latency":
            rep["latency_ms"] = {**calib.latency_ms, **truth.latency_ms}
        elif f == "junction_proximal_m":
            rep.update(junction_proximal_m=truth.junction_proximal_m, vision_tip_offset_m=0.0)
        else:
            rep[f] = getattr(truth, f)
    return dataclasses.replace(calib, **rep)


def _smoothed_sd(x: np.ndarray, n: int) -> float:
    """SD of x less its mean, after a moving average over n samples (0 when too short)."""
    if len(x) <= n or n < 1:
        return 0.0
    return float(np.convolve(x - x.mean(), np.ones(n) / n, "valid").std())


def analyse(
    session: Path, calib: Calibration | None, params: Params, sensors: str = "imu,tof,vision", swap: list[str] = ()
) -> list[dict]:
    md = read_metadata(session)
    if "calibration_truth" not in md:
        raise EvaluationError(f"{session}: not a bench session (no calibration_truth)")
    s = load(session)
    if calib is None:
        calib = Calibration.from_mcap_metadata(md, where=str(session))
    calib = swapped(calib, s.truth, list(swap))
    blocks = block_windows(s.trials)
    if not blocks:
        raise EvaluationError(f"{session}: no continuous blocks (sweeps, teleop, demo)")
    states, _ = run_states(iter_inputs(session, {}), calib, params, sensors)
    if not states:
        raise EvaluationError(f"{session}: the filter published no state")
    t = np.array([x.stamp_ns for x in states], np.int64)
    tip = np.array([x.p_tip_base_m for x in states])
    err = (tip - truth_p(s, t)) * 1e3  # mm, base frame
    err_tool = np.einsum("nji,nj->ni", truth_R(s, t), err)
    sight = np.asarray(s.truth.T_base_camera)[:3, 2]  # the camera's optical axis, base frame
    rate = 1e9 / float(np.median(np.diff(t)))
    rows = []
    for name, a, b in blocks:
        k = (t >= a + (b - a) // 5) & (t < b)
        if k.sum() < 2:
            continue
        et, e = err_tool[k], err[k]
        los = e @ sight
        rows.append({
            "session": session.name,
            "block": name,
            "samples": int(k.sum()),
            "tip_rmse_mm": float(np.sqrt((e**2).sum(1).mean())),
            "tool_mean_mm": et.mean(0).tolist(),
            "tool_sd_mm": et.std(0).tolist(),
            "sight_mean_mm": float(los.mean()),
            "sight_sd_mm": float(los.std()),
            "base_mean_mm": e.mean(0).tolist(),
            "along_sd_smoothed_mm": {f"{w:g}": _smoothed_sd(et[:, 2], int(round(w * rate))) for w in SMOOTH_S},
        })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.error_frame", description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path, help="a bench session (MCAP) with continuous blocks")
    ap.add_argument("--calibration", type=Path, help="calibration YAML (default: the session's as-calibrated)")
    ap.add_argument("--params", type=Path, help="filter parameters YAML (default: the built-in ones)")
    ap.add_argument("--sensors", default="imu,tof,vision", help="the filter's sensors (default imu,tof,vision)")
    ap.add_argument("--swap", default="", help=f"calibration fields to take from the truth: {', '.join(SWAPS)}")
    ap.add_argument("--json", type=Path, help="write the rows to this file")
    a = ap.parse_args(argv)
    try:
        calib = Calibration.load_yaml(a.calibration) if a.calibration else None
        params = load_params(a.params) if a.params else Params()
        swap = [f.strip() for f in a.swap.split(",") if f.strip()]
        check_swaps(swap)
        rows = analyse(a.session, calib, params, a.sensors, swap)
    except (OSError, UserError, EvaluationError, CalibrationError, KeyError, ValueError) as e:
        print(f"error_frame: {e}", file=sys.stderr)
        return 2
    print(
        "block: tip RMSE | tool-frame mean x, y, z (SD) | along the line of sight mean (SD) | along-shaft SD smoothed"
    )
    for r in rows:
        m, sd = r["tool_mean_mm"], r["tool_sd_mm"]
        sm = ", ".join(f"{k} s {v:.2f}" for k, v in r["along_sd_smoothed_mm"].items())
        print(
            f"{r['block']}: {r['tip_rmse_mm']:.3f} | {m[0]:+.2f} ({sd[0]:.2f}), {m[1]:+.2f} ({sd[1]:.2f}), "
            f"{m[2]:+.2f} ({sd[2]:.2f}) | {r['sight_mean_mm']:+.2f} ({r['sight_sd_mm']:.2f}) | {sm}"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
