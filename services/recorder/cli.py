"""`tiplog record`: run a recorder, control a running one, or recover a truncated file."""

from __future__ import annotations

import argparse

from tiplog.pending import not_yet


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="record_command", metavar="ACTION", required=True)
    r = sub.add_parser("run", help="record every topic into a folder until interrupted")
    r.add_argument("--out-dir", default="recordings")
    r.set_defaults(func=not_yet("recording", "the recorder issue"))
    for action in ("start", "stop", "split", "mark", "status"):
        a = sub.add_parser(action, help=f"{action} on the running recorder, over the bus")
        a.set_defaults(func=not_yet(f"record {action}", "the recorder issue"))
    rc = sub.add_parser("recover", help="rebuild a valid indexed file from a truncated one")
    rc.add_argument("file")
    rc.set_defaults(func=not_yet("recovery", "the recorder issue"))
