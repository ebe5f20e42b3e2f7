"""Calibration fits: pure numpy/scipy (OpenCV for chessboards), no I/O and no bus.

One module per fit. Each takes arrays (robot reference poses in the base frame, sensor
samples, their stamps in ns), returns a result dataclass with the fitted constants and the
residual on held-out data, and raises `DegenerateDataError` (a `UserError`: one line, exit 2
from the command line) when the data cannot determine what it is asked for: too few poses,
no motion about an axis, a stream missing. `tiplog calibrate` (tiplog/calibration/cli.py)
reads recordings into these arrays and writes the results with `tiplog.calibration`.
"""

from __future__ import annotations

from tiplog.userio import UserError


class DegenerateDataError(UserError):
    """The data cannot determine the fit; the message says which fit and why."""


def require(ok: bool, fit: str, why: str) -> None:
    """Raise DegenerateDataError('<fit>: <why>') unless ok."""
    if not ok:
        raise DegenerateDataError(f"{fit}: {why}")
