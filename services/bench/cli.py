"""`tiplog sim`: simulated sessions and the fidelity report."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)
    g = sub.add_parser("generate", help="write a simulated session to MCAP, far faster than real time")
    g.add_argument("--scenario", required=True, help="built-in name or YAML file")
    g.add_argument("--out", required=True, help="MCAP file to write")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--tier", choices=["measurement", "pixel"], default="measurement")
    g.add_argument("--duration", type=float, help="seconds (default: the scenario's)")
    g.set_defaults(func=not_yet("session generation", "the bench issue"))
    r = sub.add_parser("report", help="fidelity report: the session's raw-sensor statistics beside the paper's")
    r.add_argument("recording")
    r.set_defaults(func=not_yet("the fidelity report", "the bench issue"))
