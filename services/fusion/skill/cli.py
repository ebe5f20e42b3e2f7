"""`tiplog metrics RECORDING.mcap [--estimate EST.mcap] [--segments events|trials|none] [--json OUT]
[--plots DIR] [--draws N] [--force]`: the skill-assessment metrics of a recording's tip trajectory,
per segment, each with an interval from the estimate's own uncertainty and, where the recording
holds the bench's robot reference, the same metric from the truth beside it.

The estimate: a live recording's settled stream (fusion/state_settled), or with --estimate a
`tiplog fusion run` file's fusion/state_smoothed (a --smooth run), else its fusion/state.
Segments: `events` between the event marks the dashboard and `tiplog record mark` write (the
whole recording without marks), `trials` each continuous bench trial, `none` the whole.
Definitions, filtering, thresholds and JSON keys: docs/metrics.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
from typing import Any

import numpy as np

from services.fusion.skill.assess import METRICS, MetricsParams, draw_intervals, segment_metrics
from services.fusion.skill.data import Inputs, describe, load
from tiplog.userio import UserError, atomic_output, input_mcap, output_file, plots_folder

log = logging.getLogger("tiplog.metrics")
NONNEGATIVE = {k for k in METRICS if k not in ("ldlj", "sparc")}


def register(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = __doc__
    p.add_argument("recording", help="recording (MCAP): live, or a bench session")
    p.add_argument("--estimate", help="`tiplog fusion run` output for this recording (MCAP)")
    p.add_argument("--segments", choices=("events", "trials", "none"), default="events", help="how to cut it")
    p.add_argument("--json", dest="json_out", help="result file to write (JSON)")
    p.add_argument("--plots", help="folder for PNG plots")
    p.add_argument("--draws", type=int, default=MetricsParams.draws, help="trajectories drawn per segment")
    p.add_argument("--force", action="store_true", help="overwrite existing result or plot files")
    p.set_defaults(func=run)


def plot_names(inputs: Inputs) -> list[str]:
    """The PNG files --plots writes: per segment its speed profile and working volume, and the bars."""
    names = []
    for i, s in enumerate(inputs.segments):
        stem = f"{i + 1:02d}_{re.sub(r'[^A-Za-z0-9_.-]+', '_', s.name)[:40]}"
        names += [f"{stem}_speed.png", f"{stem}_volume.png"]
    return names + ["segments.png"]


def _check_lengths(inputs: Inputs, params: MetricsParams) -> None:
    for s in inputs.segments:
        length = (s.t1_ns - s.t0_ns) * 1e-9
        if length < params.min_segment_s:
            raise UserError(
                f"segment {s.name!r} at {(s.t0_ns - inputs.t0_ns) * 1e-9:.1f} s is {length:.2f} s long: the metrics "
                f"need at least {params.min_segment_s:g} s (the low-pass filters and SPARC); "
                "merge its marks or use --segments none"
            )


def assess(inputs: Inputs, params: MetricsParams) -> dict[str, Any]:
    """Every segment's metrics with intervals and, on the bench, the truth beside them."""
    segments, series = [], []
    cover: dict[str, list[bool]] = {}
    for i, s in enumerate(inputs.segments):
        t0, t1 = (s.t0_ns - inputs.t0_ns) * 1e-9, (s.t1_ns - inputs.t0_ns) * 1e-9
        est = inputs.estimate.window(t0, t1)
        try:
            point = segment_metrics(est, params)
            bounds = draw_intervals(est, point, params, seed=i)
            truth = segment_metrics(inputs.truth.window(t0, t1), params) if inputs.truth is not None else None
        except ValueError as e:  # the estimate covers too little of the segment, or it has no motion
            raise UserError(f"segment {s.name!r} at {t0:.1f} s: {e}") from None
        rows = {}
        for key in METRICS:
            lo, hi = bounds.get(key, (None, None))
            if lo is not None and key in NONNEGATIVE:
                lo, hi = max(lo, 0.0), max(hi, 0.0)
            row = {"value": point[key], "low": lo, "high": hi}
            if truth is not None:
                row["truth"] = truth[key]
                row["error"] = point[key] - truth[key]
                if lo is not None and math.isfinite(truth[key]):
                    row["truth_in_interval"] = bool(lo <= truth[key] <= hi)
                    cover.setdefault(key, []).append(row["truth_in_interval"])
            rows[key] = row
        segments.append({"name": s.name, "start_s": t0, "end_s": t1, "metrics": rows})
        series.append((s.name, est, inputs.truth.window(t0, t1) if inputs.truth is not None else None))
    res: dict[str, Any] = {
        "source": describe(inputs),
        "params": {k: getattr(params, k) for k in params.__dataclass_fields__},
        "definitions": {k: {"unit": u, "what": w} for k, (u, w) in METRICS.items()},
        "segments": segments,
        "_series": series,
    }
    if cover:
        res["coverage"] = {k: {"segments": len(v), "in_interval": int(sum(v))} for k, v in cover.items()}
    return res


def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    a = abs(v)
    return f"{v:.0f}" if a >= 100 else f"{v:.1f}" if a >= 10 else f"{v:.2f}" if a >= 0.1 else f"{v:.4f}"


def table(res: dict[str, Any]) -> str:
    """The terminal table: per segment, every metric with its interval and the truth beside it."""
    lines = [f"{res['source']['recording']}: {res['source']['estimate_topic']} of {res['source']['estimate_file']}"]
    for seg in res["segments"]:
        lines.append(f"\n{seg['name']}  ({seg['start_s']:.1f}-{seg['end_s']:.1f} s)")
        has_truth = any("truth" in r for r in seg["metrics"].values())
        head = f"  {'metric':28s} {'value':>9s}  {'interval':>21s}"
        lines.append(head + (f" {'truth':>9s} {'error':>9s} in" if has_truth else ""))
        for key, r in seg["metrics"].items():
            iv = f"[{_fmt(r['low'])}, {_fmt(r['high'])}]" if r["low"] is not None else ""
            line = f"  {key:28s} {_fmt(r['value']):>9s}  {iv:>21s}"
            if "truth" in r:
                mark = {True: "y", False: "n"}.get(r.get("truth_in_interval"), "")
                line += f" {_fmt(r['truth']):>9s} {_fmt(r['error']):>9s} {mark}"
            lines.append(line)
    if "coverage" in res:
        cov = ", ".join(f"{k} {v['in_interval']}/{v['segments']}" for k, v in res["coverage"].items())
        lines.append(f"\ntruth in the interval: {cov}")
    return "\n".join(lines)


def public(obj: Any) -> Any:
    """The result without private keys, NaN as null, numpy scalars as numbers (for the JSON)."""
    if isinstance(obj, dict):
        return {k: public(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list | tuple):
        return [public(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def run(args: argparse.Namespace) -> int:
    recording = input_mcap(args.recording)
    estimate = input_mcap(args.estimate) if args.estimate else None
    if args.draws < 0:
        raise UserError(f"--draws: must be 0 or more, got {args.draws}")
    if args.json_out:
        output_file(args.json_out, args.force)
    plots = plots_folder(args.plots)
    params = MetricsParams(draws=args.draws)
    inputs = load(recording, estimate, args.segments, params.rate_hz)
    _check_lengths(inputs, params)
    names = plot_names(inputs)
    if plots is not None and plots.is_dir():
        for name in names:
            output_file(plots / name, args.force)
    res = assess(inputs, params)
    print(table(res))
    if args.json_out:
        with atomic_output(args.json_out, args.force) as tmp:
            tmp.write_text(json.dumps(public(res), indent=2) + "\n")
    if plots is not None:
        from services.fusion.skill.plots import write_plots

        plots.mkdir(exist_ok=True)
        for f in write_plots(res, plots, names, params, force=args.force):
            log.info("wrote %s", f)
    return 0
