"""`tiplog info`: what a recording holds."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=not_yet("info", "the recorder issue"))
