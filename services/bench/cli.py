"""`tiplog sim`: simulated sessions and the fidelity report."""

from __future__ import annotations

import argparse
import json
import sys
import time


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)
    g = sub.add_parser("generate", help="write a simulated session to MCAP, far faster than real time")
    g.add_argument(
        "--scenario",
        required=True,
        help="built-in name (static, latency, fit, translation, rotation, sweeps, teleop, demo) or YAML file",
    )
    g.add_argument("--out", required=True, help="MCAP file to write")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--tier", choices=["measurement", "pixel"], default="measurement")
    g.add_argument("--duration", type=float, help="seconds (default: the scenario's)")
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
    r.add_argument("recording")
    r.add_argument("--json", action="store_true", help="print the report as JSON")
    r.set_defaults(func=_report)


def _progress(quiet: bool):
    t0 = time.perf_counter()
    last = [""]

    def show(stage: str, frac: float) -> None:
        if quiet:
            return
        line = f"\r[{time.perf_counter() - t0:7.1f} s] {stage:<8} {100 * frac:5.1f} %"
        if line != last[0]:
            print(line, end="" if stage != "done" else "\n", file=sys.stderr, flush=True)
            last[0] = line

    return show


def _generate(args: argparse.Namespace) -> int:
    from services.bench.scenario import load_scenario
    from services.bench.session import generate

    sc = load_scenario(args.scenario, args.overrides)  # ConfigError -> exit 2 with the field named
    if args.duration is not None and args.duration <= 0:
        print(f"tiplog sim generate: --duration must be positive (got {args.duration})", file=sys.stderr)
        return 2
    try:
        summary = generate(
            sc, args.out, seed=args.seed, tier=args.tier, duration_s=args.duration, progress=_progress(args.quiet)
        )
    except RuntimeError as e:
        print(f"tiplog sim generate: {e}", file=sys.stderr)
        return 1
    t = summary["timings"]
    print(
        f"{summary['path']}: {summary['duration_s']:.1f} s of {sc.protocol} ({summary['trials']} trials), "
        f"{summary['messages']} messages in {t['total_s']:.1f} s "
        f"({summary['duration_s'] / max(t['total_s'], 1e-9):.0f}x real time)"
    )
    return 0


def _report(args: argparse.Namespace) -> int:
    from services.bench.report.fidelity import format_table, report

    try:
        rep = report(args.recording)
    except (FileNotFoundError, KeyError) as e:
        print(f"tiplog sim report: {args.recording}: not a simulated session ({e})", file=sys.stderr)
        return 2
    print(json.dumps(rep, indent=2) if args.json else format_table(rep))
    return 0
