"""The tracking filter when the sensors are worse than it assumes: teleoperated bench sessions
generated with one error source scaled at a time, full fusion beside its sensor subsets.

Rows (each a teleop session of the `paper` profile with these scenario fields scaled):

- `x1`: the profile as it is;
- `plane2`, `plane4`, `plane6`: the tangent planes' white and pose-locked noise
  (`vision.plane_white_deg`, `vision.plane_pose_deg`) times 2, 4, 6;
- `junction3`, `junction10`: the junction's depth (white and pose-locked) and lateral noise
  times 3, 10;
- `tof2`, `tof3`: the ToF's pose-locked error (`tof.pose_sd_mm`) times 2, 3;
- `burst3`, `burst10`: vision dropouts of 3 s, or 10 s, every 20 s on average
  (`vision.dropout_rate_per_min` 3, `vision.dropout_s` fixed).

Each seed's calibration comes from `tiplog calibrate block` on a fit block of that seed at the
profile's own sizes (the rows test the filter, not the calibration). For every row: full fusion
and the subsets IMU + vision, IMU + ToF and vision only; full fusion's pooled tip RMSE, the
best subset's, their paired difference with its block-bootstrap 95 % interval
(`evaluation.paired_rmse_difference`, 2 s segments), resets, and full fusion's 1-sigma
coverage: the share of scored samples and base axes whose tip error is within the filter's own
1-sigma (68 % for an honest Gaussian covariance). The filter never sees the truth or the row.

    python -m benchmarks.fusion_robustness --seeds 5101 5102 --work DIR [--rows x1,plane4,...]
        [--duration S] [--jobs 2] [--param NAME=VALUE ...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from services.bench.scenario import load_scenario

VARIANTS = ("full", "imu_vision", "imu_tof", "vision_only")


def row_overrides(row: str) -> list[str]:
    """The `--set` fields of one row, scaled from the teleop scenario's `paper` values."""
    v = load_scenario("teleop").vision
    t = load_scenario("teleop").tof
    if row == "x1":
        return []
    if row.startswith("plane"):
        k = float(row[len("plane") :])
        return [f"vision.plane_white_deg={v.plane_white_deg * k:g}", f"vision.plane_pose_deg={v.plane_pose_deg * k:g}"]
    if row.startswith("junction"):
        k = float(row[len("junction") :])
        return [
            f"vision.junction_depth_white_mm={v.junction_depth_white_mm * k:g}",
            f"vision.junction_depth_pose_mm={v.junction_depth_pose_mm * k:g}",
            f"vision.junction_lateral_px={v.junction_lateral_px * k:g}",
        ]
    if row.startswith("tof"):
        return [f"tof.pose_sd_mm={t.pose_sd_mm * float(row[3:]):g}"]
    if row.startswith("burst"):
        s = float(row[len("burst") :])
        return ["vision.dropout_rate_per_min=3", f"vision.dropout_s=[{s:g},{s:g}]"]
    raise ValueError(f"unknown row {row!r}")


ROWS = ("x1", "plane2", "plane4", "plane6", "junction3", "junction10", "tof2", "tof3", "burst3", "burst10")


def _generate(args: tuple[str, int, str, list[str], float | None]) -> str:
    from tiplog.cli import main as tiplog_main

    scenario, seed, out, sets, duration = args
    if Path(out).exists():
        return out
    argv = ["sim", "generate", "--scenario", scenario, "--seed", str(seed), "--out", out, "--quiet"]
    argv += ["--duration", str(duration)] if duration else []
    for s in sets:
        argv += ["--set", s]
    if tiplog_main(argv) != 0:
        raise RuntimeError(f"sim generate failed: {' '.join(argv)}")
    return out


def _calibrate(seed: int, work: Path) -> Path:
    from tiplog.cli import main as tiplog_main

    cal = work / f"cal_{seed}.yaml"
    if not cal.exists():
        if tiplog_main(["calibrate", "block", str(work / f"fit_{seed}.mcap"), "--out", str(cal)]) != 0:
            raise RuntimeError(f"calibrate block failed on fit_{seed}.mcap")
    return cal


def _score(truth, states) -> dict[str, Any]:
    """Pooled scoring as `evaluation.score_continuous`, plus the 1-sigma coverage."""
    from study.evaluation import Estimate, block_windows, score_continuous

    t = np.array([s.stamp_ns for s in states], np.int64)
    tip = np.array([s.p_tip_base_m for s in states], float).reshape(-1, 3)
    sig = np.array([s.tip_sigma_m for s in states], float).reshape(-1, 3)
    r = score_continuous(truth, Estimate(t, tip))
    inside = []
    for _, a, b in block_windows(truth.trials):
        sel = (t >= a) & (t <= b)
        p_true = np.stack([np.interp(t[sel], truth.t_ns, truth.tip_base_m[:, j]) for j in range(3)], 1)
        inside.append(np.abs(tip[sel] - p_true) <= sig[sel])
    cover = float(np.concatenate(inside).mean()) if inside else float("nan")
    errs = {}
    for name, ts, _, _, e in r["_series"]:
        errs[name] = (ts, e * 1e3)
    return {"rmse_mm": r["pooled"]["tip_rmse_mm"], "sigma_coverage": cover, "_errors": errs}


def _evaluate(job: tuple[str, str, dict[str, float]]) -> dict[str, Any]:
    from services.fusion.eskf.params import Params
    from services.fusion.offline.inputs import iter_inputs
    from study.ablation import run_states, variant_inputs
    from study.evaluation import block_windows, load_truth, paired_rmse_difference
    from tiplog.calibration import Calibration

    session, cal, params = job
    truth = load_truth(session)
    calib = Calibration.load_yaml(Path(cal))
    msgs = list(iter_inputs(Path(session), {}))
    out: dict[str, Any] = {"session": Path(session).name}
    for v in VARIANTS:
        use, sensors = variant_inputs(v, msgs, block_windows(truth.trials))
        states, runner = run_states(use, calib, Params(**params), sensors)
        sc = _score(truth, states)
        diag = runner.diagnostics()
        sc["resets"] = int(diag.get("resets", 0))
        out[v] = sc
    best = min(VARIANTS[1:], key=lambda v: out[v]["rmse_mm"])
    ta, ea = _pool(out["full"]["_errors"])
    tb, eb = _pool(out[best]["_errors"])
    d = paired_rmse_difference(ta, ea, tb, eb)
    out["best_subset"] = best
    out["full_minus_best"] = {k: d[k] for k in ("diff_mm", "low_mm", "high_mm")}
    for v in VARIANTS:
        out[v].pop("_errors")
    return out


def _pool(errs: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    ts = [errs[k][0] for k in errs]
    es = [errs[k][1] for k in errs]
    return np.concatenate(ts), np.concatenate(es)


def table(results: dict[str, dict[int, dict[str, Any]]]) -> str:
    head = (
        f"{'row':11} {'seed':>5} | {'full':>6} {'1-sigma':>7} {'resets':>6} | {'best subset':>11} {'its RMSE':>8} | "
        f"{'full - best [95 % interval]':>30} | {'IMU+vision':>10} {'IMU+ToF':>8} {'vision':>7}"
    )
    lines = [head, "-" * len(head)]
    for row, by_seed in results.items():
        for seed, r in by_seed.items():
            d = r["full_minus_best"]
            lines.append(
                f"{row:11} {seed:>5} | {r['full']['rmse_mm']:6.2f} {100 * r['full']['sigma_coverage']:6.0f}% "
                f"{r['full']['resets']:>6} | {r['best_subset']:>11} {r[r['best_subset']]['rmse_mm']:8.2f} | "
                f"{d['diff_mm']:+7.2f} [{d['low_mm']:+6.2f}, {d['high_mm']:+6.2f}]{'':9} | "
                f"{r['imu_vision']['rmse_mm']:10.2f} {r['imu_tof']['rmse_mm']:8.2f} {r['vision_only']['rmse_mm']:7.2f}"
            )
    lines.append(
        "tip RMSE [mm], pooled over the scored teleop blocks; 1-sigma: share of errors within the filter's sigma"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.fusion_robustness", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--work", required=True, help="folder for the generated sessions (kept and reused)")
    ap.add_argument("--rows", default=",".join(ROWS), help="comma-separated rows (default: all)")
    ap.add_argument("--duration", type=float, help="cut each teleop session to this many seconds")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--param", action="append", default=[], metavar="NAME=VALUE", help="a fusion parameter other than the built-in"
    )
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)
    rows = [r for r in args.rows.split(",") if r]
    try:
        sets = {r: row_overrides(r) for r in rows}
    except ValueError as e:
        print(f"fusion_robustness: {e}; rows: {', '.join(ROWS)}", file=sys.stderr)
        return 2
    try:
        from services.fusion.eskf.params import Params

        params: dict[str, Any] = {}
        for k, v in (p.split("=", 1) for p in args.param):
            x = float(v)
            params[k] = int(x) if isinstance(getattr(Params(), k), int) and x.is_integer() else x
        Params(**params)
    except (ValueError, TypeError, AttributeError):
        print(f"fusion_robustness: --param takes NAME=NUMBER (got {args.param})", file=sys.stderr)
        return 2
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    gen = [("fit", s, str(work / f"fit_{s}.mcap"), [], None) for s in args.seeds]
    gen += [("teleop", s, str(work / f"teleop_{s}_{r}.mcap"), sets[r], args.duration) for r in rows for s in args.seeds]
    with ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(_generate, gen))
        cals = {s: _calibrate(s, work) for s in args.seeds}
        jobs = [(str(work / f"teleop_{s}_{r}.mcap"), str(cals[s]), params) for r in rows for s in args.seeds]
        res = list(pool.map(_evaluate, jobs))
    results: dict[str, dict[int, dict[str, Any]]] = {}
    it = iter(res)
    for r in rows:
        results[r] = {s: next(it) for s in args.seeds}
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
