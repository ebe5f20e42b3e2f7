"""`tiplog info`: what a recording holds (duration, topics, types, rates, counts, gaps,
metadata)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from services.recorder.info import format_info, inspect

    path = Path(args.recording)
    if not path.is_file():
        print(f"tiplog: {path} is not a file", file=sys.stderr)
        return 2
    info = inspect(path)
    print(json.dumps(info, indent=1) if args.json else format_info(info))
    return 0
