"""Option value types for `tiplog` subcommands' argparse parsers: a number out of range or not
finite is refused while parsing, as one line naming the option (`tiplog.cli.Parser`), before
any file is read. Each returns an argparse `type=` callable."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def whole(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """A whole number in [lo, hi] (either bound optional)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number (got {text!r})") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {_range(lo, hi)} (got {v})")
        return v

    parse.__name__ = "whole number"
    return parse


def finite(
    lo: float | None = None, hi: float | None = None, lo_open: bool = False, unit: str = ""
) -> Callable[[str], float]:
    """A finite number above lo (strictly if lo_open) and at most hi (either bound optional)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number (got {text!r})") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"must be a finite number (got {text!r})")
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise argparse.ArgumentTypeError(f"must be {_range(lo, hi, lo_open, unit)} (got {text})")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be {_range(lo, hi, lo_open, unit)} (got {text})")
        return v

    parse.__name__ = "number"
    return parse


def _range(lo: float | None, hi: float | None, lo_open: bool = False, unit: str = "") -> str:
    u = f" {unit}" if unit else ""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}{u}")
    if hi is not None:
        parts.append(f"<= {hi:g}{u}")
    return " and ".join(parts)


def endpoint(listening: bool = False) -> Callable[[str], str]:
    """A Zenoh endpoint, PROTO/HOST:PORT (see tiplog.bus_config.endpoint_problem), or '' (the
    documented `--listen ''`: none, for a client that only connects)."""

    def parse(text: str) -> str:
        from tiplog.bus_config import endpoint_problem

        if text == "":
            return text
        why = endpoint_problem(text, listening)
        if why:
            raise argparse.ArgumentTypeError(why)
        return text

    parse.__name__ = "endpoint"
    return parse
