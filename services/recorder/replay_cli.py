"""`tiplog replay`: a recording back onto the bus."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    speed.add_argument("--max", action="store_true", help="as fast as possible")
    p.add_argument("--topics", nargs="*", help="only these topics")
    p.set_defaults(func=not_yet("replay", "the recorder issue"))
