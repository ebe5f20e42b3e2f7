"""Shared by subcommands whose implementation has not landed yet: a clear message, exit 2."""

from __future__ import annotations

import argparse
import sys


def not_yet(what: str, issue: str):
    def run(_args: argparse.Namespace) -> int:
        print(f"tiplog: {what} is not available in this build yet ({issue}).", file=sys.stderr)
        return 2

    return run
