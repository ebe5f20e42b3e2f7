"""`tiplog evaluate`: a bench session scored against its ground truth, by the protocol it records
(its `session.protocol` metadata), or the whole study with `--paper`.

  translation / rotation   tiplog evaluate SESSION.mcap --json R.json [--calibration FILE] [--plots DIR]
                           (runs the static-trial filter itself: displacement and relative
                           rotation between the stationary windows, no alignment)
  static                   tiplog evaluate SESSION.mcap --json R.json [--calibration FILE]
                           (raw-stream noise per hold, the tracking filter's jitter and drift)
  sweeps, teleop, demo     tiplog evaluate SESSION.mcap --estimate OUT.mcap --json R.json [--plots DIR]
                           (tip error of `tiplog fusion run`'s output, first 20 % of each block
                           excluded), and/or --ablations [--jobs J]: every sensor subset and
                           degraded vision re-run on the recording
  the whole study          tiplog evaluate --paper [--out DIR] [--seed N] [--quick] [--jobs J]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from study.evaluation import (
    CONTINUOUS_PROTOCOLS,
    COVERAGE_WARN,
    EvaluationError,
    block_windows,
    coverage_note,
    evaluate,
    plot,
    public,
)
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import read_metadata
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file, plots_folder

log = logging.getLogger("tiplog.evaluate")
STATIC_PROTOCOLS = ("translation", "rotation")


def register(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = __doc__
    p.add_argument("session", nargs="?", help="bench session (MCAP) with ground truth (bench/robot, trials)")
    p.add_argument("--estimate", help="MCAP written by `tiplog fusion run` (continuous sessions)")
    p.add_argument("--json", dest="json_out", help="result file to write (JSON)")
    p.add_argument(
        "--topic",
        help="estimate topic (default: fusion/state_settled if the file has it, a live recording, else fusion/state; "
        "fusion/state_smoothed for --smooth runs)",
    )
    p.add_argument("--calibration", help="calibration YAML for the filters run here (default: the session's own)")
    p.add_argument("--plots", help="folder for PNG plots")
    p.add_argument("--ablations", action="store_true", help="continuous session: every sensor subset and degradation")
    p.add_argument("--jobs", type=int, help="worker processes (default: the number of cores)")
    p.add_argument("--paper", action="store_true", help="the whole study on the bench, one report")
    p.add_argument("--out", help="--paper: report folder (default paper_report)")
    p.add_argument("--seed", type=int, help="--paper: bench seed (default 1)")
    p.add_argument(
        "--quick", action="store_true", help="--paper: short sessions (a smoke test, not the paper's figures)"
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing result file or report folder")
    p.set_defaults(func=run)


def protocol_of(path: Path) -> str:
    """The session's protocol from its metadata (`session.protocol`), or UserError."""
    try:
        md = read_metadata(path)
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file for the user
        raise UserError(f"{path}: cannot read the MCAP metadata ({type(e).__name__})") from None
    proto = md.get("session", {}).get("protocol", "")
    if not proto or "trials" not in md:
        raise UserError(f"{path}: not a bench session with ground truth (no session.protocol / trials metadata)")
    return proto


def _planned_plots(session: Path, proto: str, args: argparse.Namespace) -> list[str]:
    """Names of the PNG files this run will write into --plots, known before any work: one per
    continuous block (with --estimate) and ablations.png (with --ablations), or the boxplots of
    the kinds of trial a translation / rotation session holds."""
    trials = json.loads(read_metadata(session).get("trials", {}).get("json", "[]") or "[]")
    if proto in STATIC_PROTOCOLS:
        kinds = {str(t.get("kind")) for t in trials if isinstance(t, dict)}
        return [f"{k}_boxplots.png" for k in STATIC_PROTOCOLS if k in kinds]
    if proto not in CONTINUOUS_PROTOCOLS:
        return []
    names = [f"{name}.png" for name, _, _ in block_windows(trials)] if args.estimate else []
    return names + (["ablations.png"] if args.ablations else [])


def _check_plots(plots: Path | None, names: list[str], force: bool) -> None:
    """Refuse, before any work, a plot that would replace an existing file without --force."""
    if plots is None or not plots.is_dir():
        return
    for name in dict.fromkeys(names):
        output_file(plots / name, force)


def _calibration(arg: str | None) -> Calibration | None:
    if not arg:
        return None
    try:
        return Calibration.load_yaml(input_file(arg, "calibration file"))
    except CalibrationError as e:
        raise UserError(str(e)) from None


def _jobs(n: int | None) -> int | None:
    if n is not None and n < 1:
        raise UserError(f"--jobs: must be 1 or more, got {n}")
    return n


def _write(path: str, res: dict[str, Any], force: bool) -> None:
    with atomic_output(path, force) as tmp:
        tmp.write_text(json.dumps(public(res), indent=2) + "\n")


def run(args: argparse.Namespace) -> int:
    if args.paper:
        if args.session or args.estimate or args.json_out or args.ablations:
            raise UserError("--paper: takes no SESSION, --estimate, --json or --ablations (it makes its own sessions)")
        from study import paper

        return paper.run(args)
    if args.out or args.quick or args.seed is not None:
        raise UserError("--out, --seed, --quick: only with --paper (use --json for a session's result)")
    cal = _calibration(args.calibration)  # a bad file that was given is named before what is missing
    if not args.session:
        raise UserError("give a bench session (SESSION.mcap), or --paper for the whole study")
    if not args.json_out:
        raise UserError("--json: required (the result file to write)")
    session = input_mcap(args.session)
    if args.estimate:
        input_mcap(args.estimate)  # an input before the outputs, which must not replace it
    output_file(args.json_out, args.force)
    plots = plots_folder(args.plots)
    jobs = _jobs(args.jobs)
    proto = protocol_of(session)
    try:
        _check_plots(plots, _planned_plots(session, proto, args), args.force)
    except (ValueError, TypeError, KeyError):  # unreadable trials: named by the evaluation below
        pass
    if proto in STATIC_PROTOCOLS or proto == "static":
        if args.estimate or args.ablations:
            raise UserError(f"--estimate/--ablations: not for a {proto} session (its filter is run here)")
        return _run_static(session, proto, cal, plots, args)
    if proto not in CONTINUOUS_PROTOCOLS:
        raise UserError(
            f"{session}: a {proto} session has no accuracy evaluation (calibrate with it: `tiplog calibrate block|latency`)"
        )
    if not args.estimate and not args.ablations:
        raise UserError(
            f"--estimate: required for a {proto} session; run `tiplog fusion run {session} --out EST.mcap` first "
            "(or give --ablations to run the filter's variants here)"
        )
    res: dict[str, Any] = {"session": str(session), "protocol": proto}
    if args.estimate:
        estimate = input_mcap(args.estimate)
        try:
            res |= evaluate(session, estimate, args.topic)
        except EvaluationError as e:
            raise UserError(str(e)) from None
        _print_continuous(res)
    if args.ablations:
        from study.ablation import run_ablations

        cal_file = Path(args.calibration) if args.calibration else None
        res |= run_ablations(session, cal_file, jobs, progress=lambda s: print(s, flush=True))
    _write(args.json_out, res, args.force)
    if plots is not None:
        plots.mkdir(exist_ok=True)
        files = plot(res, plots, force=args.force) if "_series" in res else []
        if args.ablations:
            from study.plots import ablation_bars

            files.append(ablation_bars({session.stem: res}, plots, force=args.force))
        for f in files:
            log.info("wrote %s", f)
    return 0


def _print_continuous(result: dict[str, Any]) -> None:
    p = result["pooled"]
    print(
        f"{result['estimate_topic']} pooled: tip RMSE {p['tip_rmse_mm']:.2f} mm, median {p['tip_median_mm']:.2f}, p95 {p['tip_p95_mm']:.2f}, "
        f"radial {p['radial_rmse_mm']:.2f}, tangential {p['tangential_rmse_mm']:.2f} ({p['samples']} samples)"
    )
    for b in result["blocks"]:
        print(
            f"  {b['name']:<14} RMSE {b['tip_rmse_mm']:.2f} mm  median {b['tip_median_mm']:.2f}  p95 {b['tip_p95_mm']:.2f}"
            + coverage_note(b["coverage"], "estimate ")
        )
    if p["coverage"] < COVERAGE_WARN:
        print(
            f"warning: the estimate covers only {100 * p['coverage']:.0f} % of the scored time; the errors are over that part"
        )


def _run_static(session: Path, proto: str, cal: Calibration | None, plots: Path | None, args) -> int:
    if proto == "static":
        from study.holds import evaluate_holds, markdown

        try:
            res = evaluate_holds(session, cal)
        except EvaluationError as e:
            raise UserError(str(e)) from None
        _write(args.json_out, res, args.force)
        sys.stdout.write(markdown(res) + "\n")
        return 0
    from study.static import evaluate_static, markdown

    res = evaluate_static(session, cal)
    _write(args.json_out, res, args.force)
    sys.stdout.write(markdown(res) + "\n")
    if plots is not None:
        from study.plots import protocol_boxplots

        plots.mkdir(exist_ok=True)
        for f in protocol_boxplots(res, plots, force=args.force):
            log.info("wrote %s", f)
    return 0
