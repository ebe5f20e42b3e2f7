"""How much of each skill metric is estimation error: `tiplog metrics` on bench sessions beside the
robot's truth, pooled over sessions, and the effect of the low-pass cut-off on both.

    python -m benchmarks.metrics_accuracy SESSION:EST [SESSION:EST ...] [--draws N] [--cutoffs 1,2,4,8]
        [--json OUT]

SESSION: a bench session (with bench/robot); EST: `tiplog fusion run SESSION --smooth` output.
Per metric: the mean over segments of the estimate, the truth and their difference, the largest
difference, the mean interval width, and how many segments' truths lie in their interval. With
--cutoffs, the mean absolute estimate-minus-truth difference per metric at each cut-off (paths
and speeds filtered alike), draws off.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from services.fusion.skill.assess import METRICS, MetricsParams, segment_metrics
from services.fusion.skill.cli import assess, public
from services.fusion.skill.data import load


def _pairs(specs: list[str]) -> list[tuple[Path, Path]]:
    out = []
    for s in specs:
        session, _, est = s.partition(":")
        out.append((Path(session), Path(est)))
    return out


def pooled(results: list[dict]) -> dict[str, dict[str, float]]:
    """Per metric over every segment of every result: means, worst difference, interval width, coverage."""
    table = {}
    for key in METRICS:
        rows = [s["metrics"][key] for r in results for s in r["segments"]]
        rows = [x for x in rows if x.get("truth") is not None and np.isfinite(x["value"]) and np.isfinite(x["truth"])]
        if not rows:
            continue
        diff = np.array([x["value"] - x["truth"] for x in rows])
        width = [x["high"] - x["low"] for x in rows if x["low"] is not None]
        inside = [x["truth_in_interval"] for x in rows if "truth_in_interval" in x]
        table[key] = {
            "estimate": float(np.mean([x["value"] for x in rows])),
            "truth": float(np.mean([x["truth"] for x in rows])),
            "diff_mean": float(diff.mean()),
            "diff_max_abs": float(np.abs(diff).max()),
            "width_mean": float(np.mean(width)) if width else float("nan"),
            "in_interval": int(sum(inside)),
            "segments": len(inside) if inside else len(rows),
        }
    return table


def cutoff_effect(pairs, cutoffs: list[float]) -> dict[str, dict[str, float]]:
    """{cut-off: {metric: mean |estimate - truth| over segments}}, and the truth's own mean."""
    out: dict[str, dict[str, float]] = {}
    for fc in cutoffs:
        params = replace(MetricsParams(draws=0), path_cutoff_hz=fc, speed_cutoff_hz=fc)
        errs: dict[str, list[float]] = {}
        for session, est in pairs:
            inp = load(session, est, "trials", params.rate_hz)
            for s in inp.segments:
                t0, t1 = (s.t0_ns - inp.t0_ns) * 1e-9, (s.t1_ns - inp.t0_ns) * 1e-9
                e = segment_metrics(inp.estimate.window(t0, t1), params)
                g = segment_metrics(inp.truth.window(t0, t1), params)
                for k in METRICS:
                    errs.setdefault(k, []).append(abs(e[k] - g[k]))
                    errs.setdefault(f"{k}.truth", []).append(g[k])
        out[f"{fc:g}"] = {k: float(np.nanmean(v)) for k, v in errs.items()}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.metrics_accuracy", description=__doc__.split("\n")[0])
    ap.add_argument("pairs", nargs="+", help="SESSION.mcap:EST.mcap")
    ap.add_argument("--draws", type=int, default=MetricsParams.draws)
    ap.add_argument("--segments", default="trials", choices=("trials", "events", "none"))
    ap.add_argument("--cutoffs", help="comma list of cut-off frequencies [Hz] to compare")
    ap.add_argument("--json", dest="json_out")
    args = ap.parse_args(argv)
    pairs = _pairs(args.pairs)
    params = MetricsParams(draws=args.draws)
    results = []
    for session, est in pairs:
        res = assess(load(session, est, args.segments, params.rate_hz), params)
        results.append(public(res))
        print(f"{session.name}: {len(res['segments'])} segments", flush=True)
    table = pooled(results)
    print(f"\n{'metric':28s} {'estimate':>10s} {'truth':>10s} {'diff':>9s} {'|diff|max':>9s} {'width':>9s}  in")
    for k, r in table.items():
        print(
            f"{k:28s} {r['estimate']:10.4g} {r['truth']:10.4g} {r['diff_mean']:9.3g} {r['diff_max_abs']:9.3g} "
            f"{r['width_mean']:9.3g}  {r['in_interval']}/{r['segments']}"
        )
    out = {"pooled": table, "results": results}
    if args.cutoffs:
        cuts = [float(c) for c in args.cutoffs.split(",")]
        out["cutoffs"] = cutoff_effect(pairs, cuts)
        keys = ("path_length_mm", "depth_path_mm", "idle_time_s", "movements", "peak_speed_mmps", "ldlj", "sparc")
        print(
            f"\nmean |estimate - truth| by cut-off (truth's mean in brackets)\n{'cut-off':>8s} "
            + " ".join(f"{k[:14]:>22s}" for k in keys)
        )
        for fc, row in out["cutoffs"].items():
            print(f"{fc:>8s} " + " ".join(f"{row[k]:9.3g} [{row[k + '.truth']:10.4g}]" for k in keys))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(public(out), indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
