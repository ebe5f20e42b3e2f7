"""`tiplog evaluate`: the paper's tables and plots from runs against the ground truth."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="+", help="MCAP sessions with ground truth (bench/robot)")
    p.add_argument(
        "--protocol",
        choices=["translation", "rotation", "sweeps", "teleop", "ablation", "degraded"],
        help="which table to produce",
    )
    p.add_argument("--out", default="results", help="folder for tables (Markdown, JSON) and PNG plots")
    p.set_defaults(func=not_yet("evaluation", "the evaluation issue"))
