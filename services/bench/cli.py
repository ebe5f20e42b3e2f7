"""`tiplog sim`: simulated sessions and the fidelity report."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from tiplog.cliargs import finite, whole
from tiplog.progress import Progress


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)
    g = sub.add_parser("generate", help="write a simulated session to MCAP, far faster than real time")
    g.add_argument(
        "--scenario",
        required=True,
        help="built-in name (static, latency, fit, translation, rotation, sweeps, teleop, demo) or YAML file",
    )
    g.add_argument(
        "--out", required=True, metavar="FILE", help="MCAP file to write (never overwritten without --force)"
    )
    g.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    g.add_argument("--seed", type=whole(0), default=0, help="random seed, 0 or more (default 0)")
    g.add_argument("--tier", choices=["measurement", "pixel"], default="measurement")
    g.add_argument(
        "--duration", type=finite(0, 1e5, lo_open=True), metavar="S", help="seconds (default: the scenario's)"
    )
    g.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="override a scenario field, e.g. --set tof.noise_sd_mm=4 (repeatable)",
    )
    g.add_argument("--quiet", action="store_true", help="no progress on stderr")
    g.set_defaults(func=_generate)
    r = sub.add_parser("report", help="fidelity report: the session's raw-sensor statistics beside the paper's")
    r.add_argument("recording", metavar="FILE", help="MCAP file of a simulated session")
    r.add_argument("--json", action="store_true", help="print the report as JSON")
    r.set_defaults(func=_report)


def _progress(p: Progress):
    t0 = time.perf_counter()

    def show(stage: str, frac: float) -> None:
        p.update(f"[{time.perf_counter() - t0:7.1f} s] {stage:<8} {100 * frac:5.1f} %", force=stage == "done")

    return show


def _generate(args: argparse.Namespace) -> int:
    from services.bench.scenario import BUILTIN, load_scenario
    from services.bench.session import generate
    from services.bench.simulation import duration_problem
    from tiplog.userio import UserError, atomic_output, output_file, register_input

    if args.scenario not in BUILTIN and Path(args.scenario).is_file():
        register_input(args.scenario, "scenario file")  # never replaced by --out
    output_file(args.out, args.force)  # before any work: a bad --out costs nothing
    sc = load_scenario(args.scenario, args.overrides)  # ConfigError -> exit 2 with the field named
    what = "--duration" if args.duration is not None else f"the scenario's duration_s ({args.scenario})"
    problem = duration_problem(sc, args.duration if args.duration is not None else sc.duration_s, what)
    if problem:
        raise UserError(problem)
    # Written under a temporary name and renamed when complete: Ctrl-C leaves nothing under --out.
    with atomic_output(args.out, args.force) as tmp, Progress(sys.stderr, enabled=not args.quiet) as p:
        summary = generate(sc, tmp, seed=args.seed, tier=args.tier, duration_s=args.duration, progress=_progress(p))
    t = summary["timings"]
    print(
        f"{args.out}: {summary['duration_s']:.1f} s of {sc.protocol} ({summary['trials']} trials), "
        f"{summary['messages']} messages in {t['total_s']:.1f} s "
        f"({summary['duration_s'] / max(t['total_s'], 1e-9):.0f}x real time)"
    )
    return 0


def _report(args: argparse.Namespace) -> int:
    from services.bench.report.fidelity import format_table, report
    from tiplog.userio import UserError, input_mcap

    path = input_mcap(args.recording)
    try:
        rep = report(path)
    except (FileNotFoundError, KeyError) as e:
        raise UserError(f"{path}: not a simulated session (no {e} in it)") from None
    print(json.dumps(rep, indent=2) if args.json else format_table(rep))
    return 0
