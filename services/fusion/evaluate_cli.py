"""`tiplog evaluate SESSION.mcap --estimate OUT.mcap --json RESULT.json [--plots DIR]`: the tip
error of an estimate against the bench's ground truth, for the continuous blocks (programmed
sweeps, teleoperated, demo): per block and pooled, first 20 % of each block excluded."""

from __future__ import annotations

import argparse
import json
import logging
import os
from pathlib import Path

from services.fusion.evaluation import EvaluationError, evaluate, plot, public
from tiplog.userio import UserError, atomic_output, input_mcap, output_file

log = logging.getLogger("tiplog.evaluate")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", help="bench session (MCAP) with ground truth (bench/robot, trials)")
    p.add_argument("--estimate", required=True, help="MCAP written by `tiplog fusion run` (fusion/state)")
    p.add_argument("--json", required=True, dest="json_out", help="result file to write (JSON)")
    p.add_argument("--topic", default="fusion/state", help="estimate topic (fusion/state_smoothed for --smooth runs)")
    p.add_argument("--plots", help="folder for PNG plots (tip path and error over time per block)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    session = input_mcap(args.session)
    estimate = input_mcap(args.estimate)
    output_file(args.json_out, args.force)
    plots = None
    if args.plots:
        plots = Path(args.plots)
        if plots.exists() and not plots.is_dir():
            raise UserError(f"{plots}: exists and is not a folder")
        if not plots.parent.is_dir() or not os.access(plots.parent, os.W_OK):
            raise UserError(f"{plots}: cannot create the folder here")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise UserError("--plots needs matplotlib (pip install 'tiplog[plots]')") from None
    try:
        result = evaluate(session, estimate, args.topic)
    except EvaluationError as e:
        raise UserError(str(e)) from None
    with atomic_output(args.json_out, args.force) as tmp:
        tmp.write_text(json.dumps(public(result), indent=2) + "\n")
    p = result["pooled"]
    print(
        f"pooled: tip RMSE {p['tip_rmse_mm']:.2f} mm, median {p['tip_median_mm']:.2f}, p95 {p['tip_p95_mm']:.2f}, "
        f"radial {p['radial_rmse_mm']:.2f}, tangential {p['tangential_rmse_mm']:.2f} ({p['samples']} samples)"
    )
    for b in result["blocks"]:
        print(
            f"  {b['name']:<14} RMSE {b['tip_rmse_mm']:.2f} mm  median {b['tip_median_mm']:.2f}  p95 {b['tip_p95_mm']:.2f}"
        )
    if plots is not None:
        plots.mkdir(exist_ok=True)
        for f in plot(result, plots):
            log.info("wrote %s", f)
    return 0
