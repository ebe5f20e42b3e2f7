"""Per-topic counts of the recorder and the bounds of its queue, shared by Zenoh's callback
threads (received, upstream gaps, dropped on overflow) and the writer thread (written, dropped
on a failed write). Everything under one lock; nothing here touches the disk."""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass

from services.recorder.timegaps import TimeGaps
from tiplog.bus import SampleInfo


@dataclass
class TopicCounts:
    received: int = 0
    written: int = 0
    dropped: int = 0
    upstream_gaps: int = 0
    time_gaps: int = 0
    time_gap_s: float = 0.0

    def as_dict(self) -> dict[str, int | float]:
        return {
            "received": self.received,
            "written": self.written,
            "dropped": self.dropped,
            "upstream_gaps": self.upstream_gaps,
            "time_gaps": self.time_gaps,
            "time_gap_s": round(self.time_gap_s, 3),
        }


class Counting:
    """Counts per topic and the queue's size in bytes and messages (bounded)."""

    def __init__(self, max_queue_bytes: int, max_queue_messages: int):
        self.max_queue_bytes = max_queue_bytes
        self.max_queue_messages = max_queue_messages
        self._lock = threading.Lock()
        self._counts: dict[str, TopicCounts] = collections.defaultdict(TopicCounts)
        self._last_seq: dict[tuple[str, int], int] = {}
        self._arrivals: dict[str, TimeGaps] = collections.defaultdict(TimeGaps)
        self._queued_bytes = 0
        self._queued_msgs = 0

    def missed(self, topic: str) -> None:
        """Received while a session cut short by a fault is missing it."""
        with self._lock:
            c = self._counts[topic]
            c.received += 1
            c.dropped += 1

    def admit(self, info: SampleInfo, size: int) -> bool:
        """Count a received message (and a sequence gap before it); True when it fits in the
        queue, else it is counted as dropped."""
        with self._lock:
            c = self._counts[info.topic]
            c.received += 1
            if info.type_name:
                k = (info.topic, info.publisher_id)
                last = self._last_seq.get(k)
                if last is not None and info.seq > last + 1:
                    c.upstream_gaps += info.seq - last - 1
                self._last_seq[k] = info.seq if last is None else max(last, info.seq)
            gaps = self._arrivals[info.topic]
            if gaps.add(info.receive_ns):
                c.time_gaps, c.time_gap_s = gaps.count, gaps.missing_s
            if self._queued_bytes + size > self.max_queue_bytes or self._queued_msgs >= self.max_queue_messages:
                c.dropped += 1
                return False
            self._queued_bytes += size
            self._queued_msgs += 1
            return True

    def dequeued(self, size: int) -> None:
        with self._lock:
            self._queued_bytes -= size
            self._queued_msgs -= 1

    def unrecorded(self, topic: str, dropped: bool) -> None:
        """Dequeued with no file open: a drop after a fault, else as if never received (it
        arrived while a stop was on its way)."""
        with self._lock:
            c = self._counts[topic]
            if dropped:
                c.dropped += 1
            else:
                c.received -= 1

    def drop(self, topic: str) -> int:
        """Count a failed write; returns the topic's drops so far."""
        with self._lock:
            c = self._counts[topic]
            c.dropped += 1
            return c.dropped

    def rejected(self, quarantine_topic: str, kept: bool) -> int:
        """A payload rejected by the admission check (already counted as received on its own
        topic), under its `_rejected/<topic>:<reason>` entry: received there, and written
        when kept in the quarantine channel, else dropped. Returns the entry's count."""
        with self._lock:
            c = self._counts[quarantine_topic]
            c.received += 1
            if kept:
                c.written += 1
            else:
                c.dropped += 1
            return c.received

    def written(self, topic: str) -> None:
        with self._lock:
            self._counts[topic].written += 1

    def reset(self) -> None:
        """A new session: counts and sequence tracking start again."""
        with self._lock:
            self._counts.clear()
            self._last_seq.clear()
            self._arrivals.clear()

    def snapshot(self) -> dict[str, dict[str, int | float]]:
        with self._lock:
            return {t: c.as_dict() for t, c in sorted(self._counts.items())}
