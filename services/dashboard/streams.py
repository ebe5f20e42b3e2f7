"""What the dashboard knows about the bus besides the state: per-topic rates and drops, service
health from liveliness tokens, and the working envelope visited so far.

All `on_*` methods run on Zenoh's threads and only count or store under a lock; the
snapshots are built on the web server's side.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tiplog.clock import now_ns

# Which streams show that a service is doing its work (prefixes of topics it publishes).
SERVICE_TOPICS: dict[str, tuple[str, ...]] = {
    "bench": ("bench/",),
    "sensor_gateway": ("device/",),
    "vision": ("vision/",),
    "fusion": ("fusion/",),
    "recorder": ("recorder/",),
    "dashboard": (),
}

# Liveliness tokens of tiplog's own tools, not services: `tiplog up`'s router session, a
# standalone router, `tiplog replay`. Kept out of the services table.
TOOL_TOKENS = frozenset({"up", "router", "replay"})


@dataclass
class _TopicCount:
    count: int = 0
    gaps: int = 0
    last_ns: int = 0
    last_seq: dict[int, int] = field(default_factory=dict)  # publisher id -> last bus seq
    rate_hz: float = 0.0


class StreamStats:
    """Per-topic counts, rates and sequence gaps. A rate is the count over the last
    `rate_window_s` (the counts are taken at each refresh, so a sample costs nothing more): over
    one status period alone, a 1 Hz topic read 0 and 2 Hz in turn."""

    def __init__(self, rate_window_s: float = 5.0, clock: Callable[[], int] = now_ns) -> None:
        self._topics: dict[str, _TopicCount] = {}
        self._lock = threading.Lock()
        self._seen = threading.Condition(self._lock)
        self._clock = clock
        self._window_ns = int(rate_window_s * 1e9)
        self._rate_ns = clock()
        # (time, {topic: count}) at each refresh, the oldest at most one refresh past the window
        self._history: deque[tuple[int, dict[str, int]]] = deque([(self._rate_ns, {})])

    def on_sample(self, topic: str, seq: int, publisher_id: int, receive_ns: int) -> None:
        with self._lock:
            tc = self._topics.get(topic)
            if tc is None:
                tc = self._topics[topic] = _TopicCount()
            tc.count += 1
            tc.last_ns = receive_ns
            prev = tc.last_seq.get(publisher_id)
            if prev is not None and seq > prev + 1:
                tc.gaps += seq - prev - 1
            tc.last_seq[publisher_id] = seq
            self._seen.notify_all()

    def wait_count(self, topic: str, n: int, timeout_s: float) -> bool:
        """Block until `topic` has been seen at least `n` times."""
        with self._seen:
            return self._seen.wait_for(lambda: topic in self._topics and self._topics[topic].count >= n, timeout_s)

    def last_seen_ns(self, prefixes: tuple[str, ...]) -> int:
        """Newest arrival on any topic starting with one of `prefixes` (0: never)."""
        with self._lock:
            return max((tc.last_ns for t, tc in self._topics.items() if t.startswith(prefixes)), default=0)

    def snapshot(self, min_period_s: float = 0.25) -> dict[str, dict[str, float]]:
        """{topic: {count, rate_hz, dropped, age_s}}; rates are refreshed at most every
        `min_period_s`, each over the last `rate_window_s` (less while the dashboard is younger)."""
        t = self._clock()
        with self._lock:
            if t - self._rate_ns >= min_period_s * 1e9:
                h = self._history
                while len(h) > 1 and t - h[1][0] >= self._window_ns:
                    h.popleft()
                t0, counts0 = h[0]
                for topic, tc in self._topics.items():
                    tc.rate_hz = (tc.count - counts0.get(topic, 0)) / ((t - t0) / 1e9)
                h.append((t, {topic: tc.count for topic, tc in self._topics.items()}))
                self._rate_ns = t
            return {
                topic: {
                    "count": tc.count,
                    "rate_hz": round(tc.rate_hz, 1),
                    "dropped": tc.gaps,
                    "age_s": round((t - tc.last_ns) / 1e9, 3),
                }
                for topic, tc in sorted(self._topics.items())
            }


class Health:
    """Services by liveliness token: up (token and fresh streams), stale (token, streams silent
    longer than `stale_after_s`), down (no token)."""

    def __init__(self, streams: StreamStats, stale_after_s: float):
        self._streams = streams
        self._stale_ns = int(stale_after_s * 1e9)
        self._alive: dict[str, bool] = {}
        self._changed_ns: dict[str, int] = {}
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)

    def on_token(self, service: str, alive: bool) -> None:
        with self._lock:
            self._alive[service] = alive
            self._changed_ns[service] = now_ns()
            self._changed.notify_all()

    def wait_token(self, service: str, alive: bool, timeout_s: float) -> bool:
        """Block until `service`'s token is seen as `alive` (True) or gone (False)."""
        with self._changed:
            return self._changed.wait_for(lambda: self._alive.get(service, False) == alive, timeout_s)

    def snapshot(self) -> dict[str, dict[str, object]]:
        """{service: {state: up|stale|down, since_s, last_data_age_s}} for the known services
        and any other service's token seen (not the tools': TOOL_TOKENS)."""
        t = now_ns()
        with self._lock:
            names = sorted(set(SERVICE_TOPICS) | (set(self._alive) - TOOL_TOKENS))
            alive = dict(self._alive)
            changed = dict(self._changed_ns)
        out: dict[str, dict[str, object]] = {}
        for name in names:
            prefixes = SERVICE_TOPICS.get(name, ())
            last = self._streams.last_seen_ns(prefixes) if prefixes else 0
            age_s = (t - last) / 1e9 if last else None
            if not alive.get(name, False):
                state = "down"
            elif prefixes and (last == 0 or t - last > self._stale_ns):
                state = "stale"
            else:
                state = "up"
            since = changed.get(name)
            out[name] = {
                "state": state,
                "token": alive.get(name, False),
                "since_s": round((t - since) / 1e9, 1) if since else None,
                "last_data_age_s": round(age_s, 3) if age_s is not None else None,
            }
        return out


class Envelope:
    """Occupancy of insertion depth x tilt visited so far (every state sample counts)."""

    DEPTH_MM = (80.0, 200.0, 2.0)  # lo, hi, bin
    TILT_DEG = (0.0, 40.0, 1.0)

    def __init__(self) -> None:
        d0, d1, db = self.DEPTH_MM
        t0, t1, tb = self.TILT_DEG
        self.counts = np.zeros((int((d1 - d0) / db), int((t1 - t0) / tb)), dtype=np.int64)
        self.depth_range_mm = [np.inf, -np.inf]
        self.tilt_max_deg = 0.0
        self._lock = threading.Lock()

    def add(self, depth_mm: float, tilt_deg: float) -> None:
        if not (np.isfinite(depth_mm) and np.isfinite(tilt_deg)):
            return
        d0, _, db = self.DEPTH_MM
        t0, _, tb = self.TILT_DEG
        i = min(max(int((depth_mm - d0) // db), 0), self.counts.shape[0] - 1)
        j = min(max(int((abs(tilt_deg) - t0) // tb), 0), self.counts.shape[1] - 1)
        with self._lock:
            self.counts[i, j] += 1
            self.depth_range_mm = [min(self.depth_range_mm[0], depth_mm), max(self.depth_range_mm[1], depth_mm)]
            self.tilt_max_deg = max(self.tilt_max_deg, abs(tilt_deg))

    def snapshot(self) -> dict[str, object]:
        """Visited cells as [[depth_bin, tilt_bin, count], ...] with the bin edges."""
        with self._lock:
            ii, jj = np.nonzero(self.counts)
            cells = [[int(i), int(j), int(self.counts[i, j])] for i, j in zip(ii, jj, strict=True)]
            lo, hi = self.depth_range_mm
            return {
                "depth_bins_mm": list(self.DEPTH_MM),
                "tilt_bins_deg": list(self.TILT_DEG),
                "cells": cells,
                "depth_min_mm": round(lo, 2) if np.isfinite(lo) else None,
                "depth_max_mm": round(hi, 2) if np.isfinite(hi) else None,
                "tilt_max_deg": round(self.tilt_max_deg, 2),
            }
