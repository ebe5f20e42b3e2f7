"""What a recording of the whole system says: per-topic rates, tip error against the bench's
truth, the depth the filter published while it started.

Times are the messages' header stamps (`stamp_ns`, the bench's CLOCK_MONOTONIC ns), so live
and offline estimates of one recording are compared over the same stretch of motion.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tiplog.mcap_io import read_messages

# Nominal rates on the simulated bench (docs/bench.md, bench-facts): Hz by topic.
NOMINAL_HZ = {
    "device/gyro": 200.0,
    "device/accel": 240.0,
    "device/tof": 100.0,
    "device/mag": 100.0,
    "bench/robot": 200.0,
    "vision/observation": 15.0,
    "fusion/state": 200.0,  # one state per gyro sample
    "fusion/tf": 200.0,
    "fusion/diagnostics": 2.0,
    "bench/tf": 30.0,
    "camera/info": 1.0,
    "device/status": 1.0,
    "recorder/status": 1.0,
    "system/supervisor": 1.0,
}


@dataclass
class TopicRate:
    count: int
    rate_hz: float  # messages per second of log time over the topic's own span
    max_gap_s: float  # longest log-time gap between consecutive messages
    seq_gaps: int  # missing publisher sequence numbers (drops between publisher and file)


def topic_rates(path: str | Path) -> dict[str, TopicRate]:
    """Per topic: count, rate over its log-time span, longest gap, sequence gaps."""
    log_ns: dict[str, list[int]] = defaultdict(list)
    seqs: dict[str, list[int]] = defaultdict(list)
    for rec in read_messages(path):
        log_ns[rec.topic].append(rec.log_time_ns)
        seqs[rec.topic].append(rec.sequence)
    out = {}
    for topic, t in log_ns.items():
        t_s = np.asarray(t, np.float64) / 1e9
        s = np.asarray(seqs[topic], np.int64)
        span = t_s[-1] - t_s[0] if len(t_s) > 1 else 0.0
        d = np.diff(np.sort(s)) if len(s) > 1 else np.zeros(0, np.int64)
        gaps = int(np.sum(np.clip(d - 1, 0, None)[d < 1_000_000]))  # ignore a restarted publisher
        out[topic] = TopicRate(
            len(t), (len(t) - 1) / span if span > 0 else 0.0, float(np.max(np.diff(t_s), initial=0)), gaps
        )
    return out


def status_changes(path: str | Path) -> int:
    """device/status messages that the gateway published at once on a change of state (state
    or message other than the previous one's), not at its period."""
    prev, n = None, 0
    for rec in read_messages(path, ["device/status"]):
        key = (rec.message.state, rec.message.message)
        n += prev is not None and key != prev
        prev = key
    return n


def supervisor_periodic(path: str | Path) -> TopicRate:
    """The rate of the supervisor's periodic reports alone: those without an event (a start, an
    exit, a restart, each reported at once) and not replayed for a recorder that came up late
    (published again in one burst with their first stamps)."""
    t = [
        rec.log_time_ns
        for rec in read_messages(path, ["system/supervisor"])
        if not rec.message.event and not rec.message.replayed
    ]
    t_s = np.asarray(t, np.float64) / 1e9
    span = t_s[-1] - t_s[0] if len(t_s) > 1 else 0.0
    return TopicRate(len(t), (len(t) - 1) / span if span > 0 else 0.0, float(np.max(np.diff(t_s), initial=0)), 0)


@dataclass
class Track:
    """Tip positions [m, base frame] at header stamps [ns], shape (N,), (N, 3)."""

    stamp_ns: np.ndarray
    p_tip_base_m: np.ndarray
    depth_mm: np.ndarray


def read_track(path: str | Path, topic: str) -> Track:
    t, p, d = [], [], []
    for rec in read_messages(path, [topic]):
        m = rec.message
        t.append(m.header.stamp_ns)
        p.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        d.append(m.depth_mm)
    if not t:
        raise ValueError(f"{path}: no messages on {topic}")
    order = np.argsort(np.asarray(t, np.int64), kind="stable")
    return Track(np.asarray(t, np.int64)[order], np.asarray(p)[order], np.asarray(d)[order])


def tip_error_mm(est: Track, truth: Track, t0_ns: int, t1_ns: int) -> np.ndarray:
    """|tip - truth| [mm] at each estimate stamp within [t0_ns, t1_ns] (truth interpolated)."""
    keep = (est.stamp_ns >= t0_ns) & (est.stamp_ns <= t1_ns)
    tq = est.stamp_ns[keep].astype(np.float64)
    tt = truth.stamp_ns.astype(np.float64)
    p_true = np.column_stack([np.interp(tq, tt, truth.p_tip_base_m[:, k]) for k in range(3)])
    return 1e3 * np.linalg.norm(est.p_tip_base_m[keep] - p_true, axis=1)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")
