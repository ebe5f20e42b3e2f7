"""`tiplog fusion run IN.mcap --out OUT.mcap`: the tracking filter over a recording."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="MCAP file with device and vision topics")
    p.add_argument("--out", required=True, help="MCAP file for the estimated trajectory")
    p.set_defaults(func=not_yet("offline fusion", "the fusion issue"))
