"""The ToF's pose-locked error, learnt online while vision gives an independent tip.

The time-of-flight range is off by a few millimetres that depend on where the beam lands and
how (3 mm across poses, 0.4 mm over repeats of one pose): a single offset b_rho follows it
while the junction is in view, but once vision is lost b_rho is held at the value of the last
pose and the depth takes the difference between poses. `TofMap` keeps, for the poses visited
with vision, the range error against the filter's geometric prediction (grouped into short
bins), and gives for a pose the kernel-weighted mean of the errors recorded near it, shrunk
towards the held b_rho where few were recorded. It is append-only in time so that a rewind
only has to cut its tail.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np


class TofMap:
    """Range errors e [m] at poses (R (3, 3), p (3,)), binned every `bin_ns`, kept `window_ns`."""

    def __init__(
        self,
        sigma_deg: float,
        sigma_mm: float,
        bin_ms: float,
        window_s: float,
        prior_weight: float,
        rewind_ms: float = 1500.0,
    ):
        # |R_i - R|_F^2 ~ 2 theta^2: the orientation part of the distance is theta^2 / sigma^2
        self._wr = 1.0 / (2.0 * math.radians(sigma_deg) ** 2)
        self._wp = 1.0 / (sigma_mm * 1e-3) ** 2
        self.bin_ns = int(bin_ms * 1e6)
        self.window_ns = int(window_s * 1e9)
        self.prior_weight = float(prior_weight)
        # bins are distinct, so the newest `keep` entries span at least twice the window: a
        # query a rewind's length in the past still finds all it needs after a compaction
        self._keep = 2 * (self.window_ns // max(self.bin_ns, 1)) + 4
        self._K = np.empty((2 * self._keep, 12))
        self._e = np.empty(2 * self._keep)
        self._t = np.empty(2 * self._keep, np.int64)  # last sample time of each bin
        self._c = np.empty(2 * self._keep, np.int64)  # samples added up to the end of each bin
        self._n = 0
        self._added = 0
        self._pending: list[tuple[int, np.ndarray, float]] = []
        # the samples of the newest bins, as far back as a rewind may go: a rewind into a bin
        # keeps that bin's earlier samples (they are not replayed)
        self._members: deque[list[tuple[int, np.ndarray, float]]] = deque(
            maxlen=int(rewind_ms * 1e6 // max(self.bin_ns, 1)) + 2
        )

    def __len__(self) -> int:
        return self._n

    @staticmethod
    def key(R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """A pose as the map stores it (a copy: take it before an update moves the state)."""
        return np.concatenate((R.ravel(), p))

    def add(self, t_ns: int, key: np.ndarray, e: float) -> None:
        """The range error e [m] at the pose `key` (from `key()`), at time t_ns."""
        if self._pending and t_ns // self.bin_ns != self._pending[0][0] // self.bin_ns:
            self._flush()
        self._pending.append((int(t_ns), key, float(e)))
        self._added += 1

    def mark(self) -> int:
        """Where the map stands now, for `rewind` (the number of samples added)."""
        return self._added

    def _flush(self) -> None:
        pend = self._pending
        self._pending = []
        if self._n == len(self._t):  # full: keep the newest half (nothing grows)
            k = self._keep
            self._K[:k] = self._K[-k:]
            self._e[:k] = self._e[-k:]
            self._t[:k] = self._t[-k:]
            self._c[:k] = self._c[-k:]
            self._n = k
        i = self._n
        k = pend[0][1].copy()
        for _, k1, _ in pend[1:]:
            k += k1
        self._K[i] = k / len(pend)
        self._e[i] = sum(e for _, _, e in pend) / len(pend)
        self._t[i] = pend[-1][0]
        self._c[i] = self._added
        self._n += 1
        self._members.append(pend)

    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bin times (n,), pose keys (n, 12), range errors (n,)) held now, oldest first: copies."""
        n = self._n
        return self._t[:n].copy(), self._K[:n].copy(), self._e[:n].copy()

    def rewind(self, mark: int) -> None:
        """Back to where `mark()` said it stood: a rewind replays what came after, so a rewound
        run equals one that had every measurement in order. (Samples are stamped with the
        state's time, which a replayed ToF range shares with the snapshot: time cannot tell.)"""
        if mark >= self._added:
            return
        flushed = self._added - len(self._pending)
        self._added = mark
        if mark > flushed or flushed == 0:
            del self._pending[mark - flushed :]
            return
        # a bin is entered when the next one starts: at the mark, the bin ending there was open
        n = int(np.searchsorted(self._c[: self._n], mark, side="left"))
        cut, end = self._n - n, int(self._c[n])
        self._pending = []
        if len(self._members) < cut:  # further back than a rewind goes: whole bins
            self._n = int(np.searchsorted(self._c[: self._n], mark, side="right"))
            self._members.clear()
            return
        self._n = n
        for _ in range(cut):
            straddling = self._members.pop()
        self._pending = straddling[: max(0, mark - (end - len(straddling)))]

    def forget_after(self, t_ns: int) -> None:
        """Forget the samples added after t_ns (a reset: they came from a state going wrong)."""
        n = int(np.searchsorted(self._t[: self._n], t_ns, side="right"))  # bins ending by t_ns
        if n == self._n:
            later = [i for i, x in enumerate(self._pending) if x[0] > t_ns]
            if later:
                self.rewind(self._added - len(self._pending) + later[0])
            return
        j = len(self._members) - (self._n - n)  # bin n's samples, if still kept
        first = self._members[j] if j >= 0 else []
        start = int(self._c[n]) - len(first) if first else (int(self._c[n - 1]) if n else 0)
        self.rewind(start + sum(1 for x in first if x[0] <= t_ns))

    def predict(self, t_ns: int, R: np.ndarray, p: np.ndarray, prior: float) -> tuple[float, float]:
        """(the range error expected at (R, p): the errors recorded near it, shrunk to `prior`;
        the kernel weight of those errors, in bins at the pose itself)."""
        lo = int(np.searchsorted(self._t[: self._n], t_ns - self.window_ns))
        if lo >= self._n:
            return prior, 0.0
        K = self._K[lo : self._n]
        dR = K[:, :9] - R.ravel()
        dp = K[:, 9:] - p
        d2 = self._wr * np.einsum("ij,ij->i", dR, dR) + self._wp * np.einsum("ij,ij->i", dp, dp)
        w = np.exp(-0.5 * d2)
        sw = float(w.sum())
        return (float(w @ self._e[lo : self._n]) + self.prior_weight * prior) / (sw + self.prior_weight), sw
