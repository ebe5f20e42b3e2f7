"""Load shedding made visible: a service that drops work to keep real time (vision's stale
frames, the pixel tier's late renders) counts what it did and publishes a `LoadStatus` every
status period, so that the dashboard, the recording and a benchmark see it, not only a log."""

from __future__ import annotations

import threading

import numpy as np

from tiplog.clock import now_ns
from tiplog.v1 import system_pb2

BEHIND_FRACTION = 0.9  # below this share of the target rate over a period, the service is behind


class LoadMeter:
    """Events done in each period and their latencies, beside running counts; thread-safe.
    `done(latency_ms)` per event kept up with; `count(name)` for anything else (a drop);
    `status(now)` closes the period and returns its message."""

    def __init__(self, service: str, target_hz: float):
        self.service = service
        self.target_hz = float(target_hz)
        self.counts: dict[str, int] = {}
        self._lock = threading.Lock()
        self._done = 0
        self._latencies: list[float] = []
        self._since_ns: int | None = None
        self.behind = False

    def count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self.counts[name] = self.counts.get(name, 0) + n

    def done(self, latency_ms: float | None = None) -> None:
        with self._lock:
            self._done += 1
            if latency_ms is not None:
                self._latencies.append(float(latency_ms))

    def status(self, t_ns: int | None = None) -> system_pb2.LoadStatus:
        """The period since the last call (or since the first call when none: rate 0)."""
        t_ns = now_ns() if t_ns is None else t_ns
        with self._lock:
            since, self._since_ns = self._since_ns, t_ns
            done, self._done = self._done, 0
            lat, self._latencies = self._latencies, []
            counts = dict(self.counts)
        period_s = (t_ns - since) * 1e-9 if since is not None else 0.0
        hz = done / period_s if period_s > 0 else 0.0
        m = system_pb2.LoadStatus(service=self.service, target_hz=self.target_hz, achieved_hz=hz, period_s=period_s)
        m.header.stamp_ns = t_ns
        for k, v in counts.items():
            m.counts[k] = v
        if lat:
            m.latency_p95_ms = float(np.percentile(lat, 95))
        self.behind = period_s > 0 and self.target_hz > 0 and hz < BEHIND_FRACTION * self.target_hz
        m.behind = self.behind
        return m
