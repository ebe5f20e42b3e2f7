"""Tip accuracy of the tracking filter on bench sessions (continuous blocks), with the built-in
parameters: full fusion, sensor subsets, degraded vision, as the paper's tables.

Subsets and degradations (`third`, `noise5`, `blackout1/3/10`, `junction_hidden`) are those of
`study.ablation`: sixteen blackouts per session, or with `--shared-blackouts` the
paper's sixteen shared over the sessions given in proportion to their blocks (the paper's were
over one recording holding both the sweeps and the teleoperated blocks, so sixteen per session
is the harsher reading; `tiplog evaluate --paper` reports both). The
filter never sees the truth; scoring uses `study.evaluation` (first 20 % of each
block excluded). `tiplog evaluate SESSION --ablations` runs the same variants in parallel.
`smoothed` is the full fusion through the RTS smoother, as an archive gets it; `smoothed:NAME`
smooths any subset or degradation (`smoothed:blackout10`: what 10 s blackouts cost an archive).
The filter's states are the settled ones (what `tiplog fusion run` writes); `--as-live` scores
the display stream the live service published on fusion/state instead.

`--compare full:imu_vision` adds, per block, the first variant's tip RMSE less the second's with
a block-bootstrap 95 % interval (`evaluation.paired_rmse_difference`), and a tally of blocks
won, lost and lost beyond the interval. `--ratio junction_hidden:full:2` adds, per session, the
first variant's pooled tip RMSE over the second's with the same bootstrap's 95 % interval
(`evaluation.paired_rmse_ratio`) and whether the interval lies above, below or across the
target (default 1): the paper's ablation structure is stated as such ratios.

    python -m benchmarks.fusion_accuracy SESSION.mcap [...] [--variants full,imu_tof,...]
        [--calibration FILE] [--shared-blackouts] [--as-live] [--compare A:B,...]
        [--ratio A:B[:TARGET],...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from services.fusion.eskf.params import Params, ParamsError, parse_sensors
from services.fusion.offline.inputs import iter_inputs
from services.fusion.offline.smoother import smooth
from services.fusion.params_file import load_params
from study.ablation import (
    BLACKOUT_COUNT,
    DEGRADED,
    SUBSETS,
    run_variant,
    sessions_blackouts,
    variant_inputs,
)
from study.evaluation import (
    Estimate,
    EvaluationError,
    block_errors_mm,
    block_windows,
    coverage_note,
    load_truth,
    paired_rmse_difference,
    paired_rmse_ratio,
    score_continuous,
)
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError

SMOOTH = "smoothed"  # full fusion through the RTS smoother; `smoothed:VARIANT` smooths that variant


def split_variant(v: str) -> tuple[str, bool]:
    """(the ablation variant, whether it is smoothed) for a --variants entry."""
    if v == SMOOTH:
        return "full", True
    base = v.removeprefix(f"{SMOOTH}:")
    return base, base != v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sessions", nargs="+", help="bench sessions (sweeps, teleop, demo)")
    ap.add_argument(
        "--variants", default="full", help=f"comma list of {', '.join([*SUBSETS, *DEGRADED, SMOOTH])}, smoothed:NAME"
    )
    ap.add_argument("--params", help="parameter YAML (default: built-in)")
    ap.add_argument(
        "--calibration", help="calibration YAML for every session (default: each one's as-calibrated metadata)"
    )
    ap.add_argument(
        "--shared-blackouts",
        action="store_true",
        help="the paper's sixteen blackouts shared over the sessions given (default: sixteen in each)",
    )
    ap.add_argument("--as-live", action="store_true", help="score the display stream (30 ms behind), not the settled")
    ap.add_argument(
        "--compare",
        default="",
        help="comma list of A:B (variants given in --variants): per block, A's tip RMSE less B's with its "
        "block-bootstrap 95 %% interval, and a tally of blocks won, lost and lost beyond that interval",
    )
    ap.add_argument(
        "--ratio",
        default="",
        help="comma list of A:B or A:B:TARGET (variants given in --variants): per session, A's pooled tip RMSE "
        "over B's with its block-bootstrap 95 %% interval, against TARGET (default 1)",
    )
    ap.add_argument(
        "--segment-s", type=float, default=2.0, help="--compare's and --ratio's bootstrap segment (default 2 s)"
    )
    ap.add_argument("--json", help="write all results here")
    args = ap.parse_args(argv)
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    for v in variants:
        base, _ = split_variant(v)
        if base not in SUBSETS and base not in DEGRADED:
            ap.error(f"--variants: unknown variant {v!r}")
    pairs = [tuple(c.strip().split(":", 1)) for c in args.compare.split(",") if c.strip()]
    for pair in pairs:
        if len(pair) != 2 or not all(x in variants for x in pair):
            ap.error(f"--compare: {':'.join(pair)!r} is not A:B with both in --variants")
    if not args.segment_s > 0:
        ap.error(f"--segment-s: must be above 0, not {args.segment_s}")
    args.pairs = pairs
    args.ratios = [_parse_ratio(ap, r.strip(), variants) for r in args.ratio.split(",") if r.strip()]
    try:
        return _run(args, variants)
    except (CalibrationError, EvaluationError, ParamsError, UserError, OSError) as e:  # one line, no traceback
        print(f"fusion_accuracy: {e}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace, variants: list[str]) -> int:
    params = load_params(args.params) if args.params else Params()
    given = Calibration.load_yaml(args.calibration) if args.calibration else None
    output = "display" if args.as_live else "settled"
    results = []
    tally = {pair: [0, 0, 0] for pair in args.pairs}  # blocks A won, lost, lost beyond the interval
    counts = [BLACKOUT_COUNT] * len(args.sessions)
    if args.shared_blackouts:
        counts = sessions_blackouts(args.sessions)
    for path, n_blackouts in zip(args.sessions, counts, strict=True):
        truth = load_truth(path)
        calib = given if given is not None else Calibration.from_mcap_metadata(read_metadata(path), where=path)
        msgs = list(iter_inputs(Path(path), {}))
        blocks = block_windows(truth.trials)
        series = {}  # variant -> its blocks' stamps and tip errors, for --compare
        for v in variants:
            base, smoothed = split_variant(v)
            use, sensors = variant_inputs(base, msgs, blocks, seed=0, blackouts=n_blackouts)
            if smoothed:
                t0 = time.process_time()
                sm = smooth(calib, params, use, parse_sensors(sensors))
                cpu = time.process_time() - t0
                est = Estimate(np.array([s.stamp_ns for s in sm], np.int64), np.array([s.p_tip_base_m for s in sm]))
                diag = {"resets": 0}
            else:
                est, diag, cpu = run_variant(use, calib, params, sensors, output)
            r = score_continuous(truth, est)
            series[v] = block_errors_mm(r["_series"])
            row = {
                "session": Path(path).name,
                "variant": v,
                "output": "smoothed" if smoothed else output,
                "pooled": r["pooled"],
                "blocks": r["blocks"],
                "block_mean_mm": float(np.mean([b["tip_rmse_mm"] for b in r["blocks"]])),
                "cpu_s": round(cpu, 2),
                "resets": diag["resets"],
                "reset_reasons": diag.get("reset_reasons", {}),
                "reacquired": int(diag.get("updates", {}).get("reacquire", 0)),
            }
            if base.startswith("blackout"):
                row["blackouts"] = n_blackouts
            results.append(row)
            blk = " ".join(f"{b['name']}={b['tip_rmse_mm']:.2f}{coverage_note(b['coverage'])}" for b in r["blocks"])
            print(
                f"{row['session']:<22} {v:<11} pooled {r['pooled']['tip_rmse_mm']:6.2f} mm "
                f"(median {r['pooled']['tip_median_mm']:.2f}, p95 {r['pooled']['tip_p95_mm']:.2f}, "
                f"radial {r['pooled']['radial_rmse_mm']:.2f}, tangential {r['pooled']['tangential_rmse_mm']:.2f}) "
                f"[{blk}] cpu {cpu:.1f} s resets {diag['resets']} reacquired {row['reacquired']}",
                flush=True,
            )
        for a, b, target in args.ratios:
            r = pooled_ratio(series[a], series[b], target, args.segment_s)
            results.append({"session": Path(path).name, "ratio_of": f"{a}:{b}", **r})
            verdict = "above" if r["above"] else "below" if r["below"] else "a tie with"
            print(
                f"{Path(path).name:<22} {a} / {b} pooled {r['rmse_a_mm']:.3f} / {r['rmse_b_mm']:.3f} = "
                f"{r['ratio']:.2f} (95 % {r['low']:.2f} .. {r['high']:.2f}, {verdict} {target:g})",
                flush=True,
            )
        for a, b in args.pairs:
            rows = compare_blocks(series[a], series[b], args.segment_s)
            results.append({"session": Path(path).name, "compare": f"{a}:{b}", "blocks": rows})
            for c in rows:
                won = c["diff_mm"] <= 0  # a tie goes to A, as in the paper report
                t = tally[(a, b)]
                t[0 if won else 1] += 1
                t[2] += int(not won and c["resolved"])
                print(
                    f"{Path(path).name:<22} {a} - {b} {c['name']:<12} {c['rmse_a_mm']:.4f} - {c['rmse_b_mm']:.4f} = "
                    f"{c['diff_mm']:+.4f} mm (95 % {c['low_mm']:+.4f} .. {c['high_mm']:+.4f}, "
                    f"{'resolved' if c['resolved'] else 'within the block bootstrap'})",
                    flush=True,
                )
    for (a, b), (won, lost, beyond) in tally.items():
        print(
            f"{a} against {b}: better in {won} of {won + lost} blocks; worse in {lost}, beyond the interval in {beyond}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


def _parse_ratio(ap: argparse.ArgumentParser, text: str, variants: list[str]) -> tuple[str, str, float]:
    parts = text.split(":")
    target = 1.0
    if len(parts) == 3:
        try:
            target = float(parts[2])
        except ValueError:
            target = float("nan")
    if len(parts) not in (2, 3) or not all(x in variants for x in parts[:2]) or not target > 0:
        ap.error(f"--ratio: {text!r} is not A:B or A:B:TARGET with both in --variants and TARGET above 0")
    return parts[0], parts[1], target


def pooled_ratio(errors_a: dict, errors_b: dict, target: float, segment_s: float) -> dict:
    """`paired_rmse_ratio` of A's tip error over B's, every block of the session pooled."""
    ta, ea = (np.concatenate([errors_a[k][i] for k in errors_a]) for i in (0, 1))
    tb, eb = (np.concatenate([errors_b[k][i] for k in errors_b]) for i in (0, 1))
    return paired_rmse_ratio(ta, ea, tb, eb, target, segment_s)


def compare_blocks(errors_a: dict, errors_b: dict, segment_s: float) -> list[dict]:
    """Per block (two variants' `block_errors_mm`): `paired_rmse_difference` of A's tip error
    against B's, with the block's name."""
    return [
        {"name": name, **paired_rmse_difference(t_a, e_a, *errors_b[name], segment_s)}
        for name, (t_a, e_a) in errors_a.items()
    ]


if __name__ == "__main__":
    sys.exit(main())
