"""A recording back onto the bus with its original timing, or as fast as possible.

The recorded payloads are sent as they are (`Publisher.put_bytes`, no re-encode). Each message
is due at `t0 + (log_time - first_log_time) / speed` on the monotonic clock: lateness of one
put never accumulates into the next. The wait sleeps to within 0.1 ms of the due time and
spins the rest, which keeps the spacing within a fraction of a millisecond on an idle host.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from tiplog import topics
from tiplog.bus import Bus, Publisher
from tiplog.mcap_io import iter_log_time, open_reader, reading
from tiplog.mcap_salvage import Salvage, intact_messages, trailer_problem

log = logging.getLogger(__name__)
NS_PER_S = 1_000_000_000
# The last stretch before a due time is spun, not slept: a sleep overshoots by ~50-100 us.
# Short on purpose: a process that spins long loses the scheduler's wake-up preference and is
# preempted for milliseconds on a loaded host (measured: 1 ms of spin, 15% of puts >1 ms late
# at load 4 on 2 cores; 0.1 ms, 1-4%).
SPIN_NS = 100_000
# Playback speed factors: a thousandth of real time stretches a minute over 17 hours; faster
# than a thousand times, --max (as fast as possible) is what is meant.
MIN_SPEED, MAX_SPEED = 0.001, 1000.0
# A put later than this against its due time is counted late in the report.
LATE_NS = 1_000_000
# Published by the live system itself: replaying them would confuse the running services.
# `_rejected/` holds payloads the recorder kept out of their topics (admission.py): never
# published again unless named.
DEFAULT_EXCLUDE = ("recorder/", "_rejected/")


@dataclass
class ReplayReport:
    messages_by_topic: Counter = field(default_factory=Counter)
    skipped_topics: set[str] = field(default_factory=set)
    duration_s: float = 0.0
    max_late_ns: int = 0  # worst lateness of a put against its due time
    late_puts: int = 0  # puts more than LATE_NS after their due time (the host's scheduler)
    salvage: Salvage | None = None  # set for a file cut short: how far it could be read

    @property
    def messages(self) -> int:
        return sum(self.messages_by_topic.values())


def wait_until_ns(due_ns: int, stop: threading.Event | None = None) -> int:
    """Sleep, then spin, until time.monotonic_ns() >= due_ns, or until `stop` is set; returns
    how late it woke (ns; 0 when stopped)."""
    while True:
        now = time.monotonic_ns()
        left = due_ns - now
        if left <= 0:
            return -left
        if left > SPIN_NS:
            if stop is None:
                time.sleep((left - SPIN_NS) / NS_PER_S)
            elif stop.wait((left - SPIN_NS) / NS_PER_S):
                return 0


def wait_for_subscribers(
    bus: Bus, topic_names: Iterable[str], timeout_s: float, stop: threading.Event | None = None
) -> bool:
    """True once some subscriber matches one of the topics (the recorder, fusion, ...); False
    after `timeout_s` or once `stop` is set."""
    probes = [bus.session.declare_publisher(bus.key(t)) for t in topic_names]
    stop = stop or threading.Event()
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if any(p.matching_status.matching for p in probes):
                return True
            if time.monotonic() >= deadline or stop.wait(0.01):
                return False
    finally:
        for p in probes:
            p.undeclare()


def replay(
    bus: Bus,
    path: str | Path,
    *,
    speed: float = 1.0,
    as_fast_as_possible: bool = False,
    topics_: Iterable[str] | None = None,
    stop: threading.Event | None = None,
    wait_s: float = 5.0,
) -> ReplayReport:
    """Publish the messages of `path` in log-time order; returns what was sent."""
    if not as_fast_as_possible and not MIN_SPEED <= speed <= MAX_SPEED:
        raise ValueError(f"speed must be in [{MIN_SPEED:g}, {MAX_SPEED:g}] (got {speed})")
    wanted = set(topics_) if topics_ else None
    rep = ReplayReport()
    pubs: dict[str, Publisher] = {}
    with open(path, "rb") as f, reading(path):  # a damaged chunk ends the replay with where it is
        reader = open_reader(f)
        try:
            summary = None if trailer_problem(path) else reader.get_summary()
        except Exception:  # a damaged summary: read the data section as a stream
            summary = None
        if summary is not None:
            names = [c.topic for c in summary.channels.values()]
            chosen = [t for t in names if (t in wanted if wanted else not t.startswith(DEFAULT_EXCLUDE))]
            for ch in summary.channels.values():  # declared before the clock starts
                if ch.topic in chosen:
                    sch = summary.schemas.get(ch.schema_id)
                    _publisher(bus, pubs, ch.topic, sch.name if sch else "", rep)
            if wait_s > 0 and chosen and not wait_for_subscribers(bus, chosen, wait_s, stop):
                if not (stop is not None and stop.is_set()):
                    log.warning("no subscriber for %s after %.1f s; replaying anyway", ", ".join(chosen), wait_s)
        first: int | None = None
        t0 = 0
        t_start = time.monotonic_ns()
        if summary is not None:
            messages = iter_log_time(reader, f, None)
        else:  # cut short: what can be read, in file order (the recorder writes in log-time order)
            f.seek(0)
            rep.salvage = Salvage(source_bytes=Path(path).stat().st_size)
            messages = intact_messages(f, rep.salvage)
        for schema, channel, message in messages:
            if stop is not None and stop.is_set():
                break
            topic = channel.topic
            if wanted is not None and topic not in wanted or wanted is None and topic.startswith(DEFAULT_EXCLUDE):
                continue
            pub = pubs.get(topic)
            if pub is None:
                pub = _publisher(bus, pubs, topic, schema.name if schema else "", rep)
                if pub is None:
                    continue
            if first is None:
                first = message.log_time
                t0 = time.monotonic_ns() + 5_000_000  # a little lead for the first put
            if not as_fast_as_possible:
                late = wait_until_ns(t0 + int((message.log_time - first) / speed), stop)
                if stop is not None and stop.is_set():
                    break
                rep.max_late_ns = max(rep.max_late_ns, late)
                rep.late_puts += late > LATE_NS
            pub.put_bytes(message.data)
            rep.messages_by_topic[topic] += 1
    rep.duration_s = (time.monotonic_ns() - t_start) / NS_PER_S
    return rep


def _publisher(bus: Bus, pubs: dict[str, Publisher], topic: str, type_name: str, rep: ReplayReport) -> Publisher | None:
    if topic in pubs or topic in rep.skipped_topics:
        return pubs.get(topic)
    try:
        cls = topics.message_class_by_name(type_name)
    except KeyError:
        log.warning("skipping %s: schema %r not known to this build", topic, type_name)
        rep.skipped_topics.add(topic)
        return None
    pubs[topic] = bus.publisher(topic, cls)
    return pubs[topic]
