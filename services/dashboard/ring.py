"""A bounded ring of samples that many readers follow with their own cursors.

The bus callback appends one row (an int64 stamp and a float64 vector) under a lock; each
websocket sender reads what came after its cursor. Nothing grows: a reader that fell more
than `capacity` rows behind skips to the oldest row still kept, and is told how many it
missed. Rows keep their absolute index (`total` so far), so a reader never sees a row twice.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Slice:
    """Rows [start, end) in absolute indices; `skipped` rows were overwritten before reading."""

    start: int
    end: int
    stamps_ns: np.ndarray  # (n,) int64
    rows: np.ndarray  # (n, width) float64
    skipped: int


class Ring:
    """Fixed-capacity ring of (stamp_ns, row[width]) with absolute indices."""

    def __init__(self, capacity: int, width: int):
        if capacity < 1 or width < 1:
            raise ValueError(f"ring capacity and width must be >= 1 (got {capacity}, {width})")
        self.capacity = capacity
        self.width = width
        self._stamps = np.zeros(capacity, dtype=np.int64)
        self._rows = np.full((capacity, width), np.nan)
        self._total = 0
        self._lock = threading.Lock()

    @property
    def total(self) -> int:
        """Rows appended since creation (the absolute index of the next row)."""
        return self._total

    def __len__(self) -> int:
        return min(self._total, self.capacity)

    def append(self, stamp_ns: int, row: np.ndarray | list[float]) -> int:
        """Append one row; returns its absolute index."""
        with self._lock:
            k = self._total % self.capacity
            self._stamps[k] = stamp_ns
            self._rows[k] = row
            self._total += 1
            return self._total - 1

    def span(self, cursor: int, max_rows: int) -> tuple[int, int, int]:
        """(start, end, skipped) of what `read(cursor, max_rows)` would return, copying nothing:
        readers that share a cursor can share one read of it."""
        total = self._total  # one int read: atomic, and a row counted in it is already written
        oldest = max(0, total - self.capacity)
        start = max(cursor, oldest)
        return start, min(total, start + max_rows), start - cursor

    def read(self, cursor: int, max_rows: int, end: int | None = None) -> Slice:
        """Up to `max_rows` rows from absolute index `cursor` on (oldest first), or up to `end`
        when given (a span's end, so that the rows match it)."""
        with self._lock:
            start, stop, skipped = self.span(cursor, max_rows)
            end = stop if end is None else max(start, min(end, stop))
            idx = np.arange(start, end) % self.capacity
            return Slice(start, end, self._stamps[idx].copy(), self._rows[idx].copy(), skipped)

    def last(self) -> tuple[int, np.ndarray] | None:
        """The newest (stamp_ns, row), or None when empty."""
        with self._lock:
            if self._total == 0:
                return None
            k = (self._total - 1) % self.capacity
            return int(self._stamps[k]), self._rows[k].copy()
