"""The host clock every sample is stamped with on arrival."""

from __future__ import annotations

import time

NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000


def now_ns() -> int:
    """Host clock in int64 ns (CLOCK_MONOTONIC: shared by every process on the host, never
    steps back). Wall time is recorded once per session in metadata, not per sample."""
    return time.monotonic_ns()


def wall_ns() -> int:
    """Wall-clock time in ns since the Unix epoch, for file names and session metadata."""
    return time.time_ns()
