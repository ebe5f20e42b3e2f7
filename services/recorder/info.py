"""What a recording holds: duration, topics, types, rates, counts, sequence gaps, metadata.

Sequence gaps come from the MCAP `sequence` field (each publisher's bus sequence number).
A file does not say which publisher wrote a message, and two publishers may share a topic
(two gateways, a restarted service): each message continues the sequence whose last number
is the nearest below its own, a message below every known sequence starts a new one (a
restarted publisher counts nothing), and a forward jump of more than one within a sequence
counts the samples in between as lost upstream. Time gaps (`services.recorder.timegaps`) come
from the log times against the topic's own rate: an outage across a restart shows there.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.stream_reader import StreamReader

from services.recorder.timegaps import TimeGaps
from tiplog.mcap_check import DamagedRecord, metadata_records
from tiplog.mcap_io import open_reader

NS_PER_S = 1_000_000_000
MAX_SEQUENCES = 16  # publishers followed per topic at once (the least recently continued is forgotten)


@dataclass
class SequenceGaps:
    """Samples missing per sequence on one topic, with several publishers interleaved.

    A message continues the sequence whose last number is the nearest below its own, unless
    the jump is more samples than the time since that sequence's last message could hold at
    the topic's rate (twice over, plus `slack`): then it starts a sequence of its own (another
    publisher further along), as does a message below every known sequence."""

    slack: int = 50
    gaps: int = 0
    events: int = 0
    _last: dict[int, tuple[int, int]] = field(default_factory=dict)  # last number -> (order of use, log ns)
    _tick: int = 0
    _max_open: int = 0

    @property
    def sequences(self) -> int:
        """Most sequences followed at once (at most MAX_SEQUENCES): publishers sharing the
        topic, or a publisher's restarts."""
        return self._max_open

    def add(self, seq: int, log_ns: int = 0, rate_hz: float = 0.0) -> None:
        self._tick += 1
        if seq in self._last:  # a repeat: nothing new
            self._last[seq] = (self._tick, log_ns)
            return
        below = [s for s in self._last if s < seq]
        prev = max(below) if below else None
        if prev is not None:
            dt_s = max(0.0, (log_ns - self._last[prev][1]) / NS_PER_S)
            allowed = 2.0 * dt_s * rate_hz + self.slack if rate_hz > 0 else 1000
            if seq - prev - 1 > allowed:
                prev = None  # too far ahead to be this sequence's next
        if prev is not None:
            del self._last[prev]
            if seq > prev + 1:
                self.gaps += seq - prev - 1
                self.events += 1
        elif len(self._last) >= MAX_SEQUENCES:
            del self._last[min(self._last, key=lambda s: self._last[s][0])]
        self._last[seq] = (self._tick, log_ns)
        self._max_open = max(self._max_open, len(self._last))


@dataclass
class TopicInfo:
    topic: str
    type_name: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    bytes: int = 0
    seq: SequenceGaps = field(default_factory=SequenceGaps, repr=False)
    time: TimeGaps = field(default_factory=TimeGaps, repr=False)

    @property
    def gaps(self) -> int:
        """Samples missing according to the sequence numbers."""
        return self.seq.gaps

    @property
    def rate_hz(self) -> float:
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns == self.first_ns:
            return 0.0
        return (self.count - 1) * NS_PER_S / (self.last_ns - self.first_ns)

    def add(self, log_ns: int, seq: int, size: int) -> None:
        self.count += 1
        self.bytes += size
        self.first_ns = log_ns if self.first_ns is None else min(self.first_ns, log_ns)
        self.last_ns = log_ns if self.last_ns is None else max(self.last_ns, log_ns)
        self.time.add(log_ns)
        self.seq.add(seq, log_ns, self.time.expected_hz)

    def as_dict(self) -> dict[str, Any]:
        return {
            "type": self.type_name,
            "count": self.count,
            "rate_hz": round(self.rate_hz, 3),
            "first_ns": self.first_ns,
            "last_ns": self.last_ns,
            "bytes": self.bytes,
            "gaps": self.gaps,
            "gap_events": self.seq.events,
            "sequences": self.seq.sequences,
            **self.time.as_dict(),
        }


def inspect(path: str | Path) -> dict[str, Any]:
    """Everything `tiplog info` shows, as a JSON-ready dict."""
    path = Path(path)
    topics: dict[str, TopicInfo] = {}  # one topic may have several channels (several writers)
    metadata: dict[str, dict[str, str]] = {}
    attachments: list[dict[str, Any]] = []
    indexed = True
    with open(path, "rb") as f:
        reader = open_reader(f)
        try:
            summary = reader.get_summary()
        except Exception:  # no footer: a truncated file
            summary = None
        if summary is None:
            indexed = False
        f.seek(0)
        try:
            for schema, channel, message in _messages(f, indexed, metadata, attachments):
                ti = topics.get(channel.topic)
                if ti is None:
                    ti = topics[channel.topic] = TopicInfo(channel.topic, schema.name if schema else "")
                ti.add(message.log_time, message.sequence, len(message.data))
        except Exception as e:  # a truncated tail: report what was read
            metadata["_read_error"] = {"error": f"{type(e).__name__}: {e}"}
        if indexed:
            f.seek(0)
            reader = open_reader(f)
            try:  # metadata carries no CRC: each record is checked against the summary's index
                for m in metadata_records(f, reader.get_summary(), path.stat().st_size):
                    metadata[m.name] = dict(m.metadata)
            except DamagedRecord as e:
                metadata["_read_error"] = {"error": f"{type(e).__name__}: {e}", "note": f"{path}: {e}"}
            for a in reader.iter_attachments():
                attachments.append({"name": a.name, "media_type": a.media_type, "bytes": len(a.data)})
    by_topic = topics
    firsts = [t.first_ns for t in by_topic.values() if t.first_ns is not None]
    lasts = [t.last_ns for t in by_topic.values() if t.last_ns is not None]
    start, end = (min(firsts), max(lasts)) if firsts else (None, None)
    return {
        "file": str(path),
        "recorder_gaps": _recorder_gaps(metadata),
        "bytes": path.stat().st_size,
        "indexed": indexed,
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) / NS_PER_S if start is not None and end is not None else 0.0,
        "messages": sum(t.count for t in by_topic.values()),
        "gaps": sum(t.gaps for t in by_topic.values()),
        "time_gaps": sum(t.time.count for t in by_topic.values()),
        "topics": {t: ti.as_dict() for t, ti in sorted(by_topic.items())},
        "metadata": metadata,
        "attachments": attachments,
    }


def _recorder_gaps(metadata: dict[str, dict[str, str]]) -> int | None:
    """The upstream gaps the recorder counted itself, per publisher (it knows each message's
    publisher; the file does not), over its session: None when the file has no such counts
    (cut by a crash, written by another tool)."""
    counts = metadata.get("recorder_counts")
    if not counts:
        return None
    try:
        return sum(int(json.loads(v).get("upstream_gaps", 0)) for v in counts.values())
    except (ValueError, TypeError, AttributeError):
        return None


def _messages(f, indexed: bool, metadata: dict, attachments: list):  # type: ignore[no-untyped-def]
    """(schema, channel, message) in file order: indexes when present, else a stream read
    (which also fills `metadata` and `attachments`)."""
    if indexed:
        yield from open_reader(f).iter_messages(log_time_order=False)
        return
    from mcap.records import Attachment, Channel, Message, Metadata, Schema

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for rec in StreamReader(f).records:
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message) and rec.channel_id in channels:
            ch = channels[rec.channel_id]
            yield schemas.get(ch.schema_id), ch, rec
        elif isinstance(rec, Metadata):
            metadata[rec.name] = dict(rec.metadata)
        elif isinstance(rec, Attachment):
            attachments.append({"name": rec.name, "media_type": rec.media_type, "bytes": len(rec.data)})


def format_info(info: dict[str, Any]) -> str:
    """The dict of `inspect` as a human-readable report."""
    out = [
        f"file:      {info['file']} ({info['bytes'] / 2**20:.1f} MiB{'' if info['indexed'] else ', NOT INDEXED: run tiplog record recover'})",
        (
            f"duration:  {info['duration_s']:.3f} s ({info['start_ns']} .. {info['end_ns']} ns)"
            if info["start_ns"] is not None
            else "duration:  - (no complete message could be read)"
        ),
        f"messages:  {info['messages']}   sequence gaps: {info['gaps']}{_recorder_note(info)}   "
        f"time gaps: {info.get('time_gaps', 0)} (intervals over 10x the topic's own)",
        "",
    ]
    out += _topic_table(info["topics"])
    if info["attachments"]:
        out.append("")
        out.append("attachments: " + ", ".join(f"{a['name']} ({a['bytes']} B)" for a in info["attachments"]))
    if info["metadata"]:
        out.append("")
        out.append("metadata:")
        for name, data in info["metadata"].items():
            out.append(f"  {name}:")
            for k, v in data.items():
                v = v if len(v) <= 100 else v[:97] + "..."
                out.append(f"    {k}: {v}")
    return "\n".join(out)


def _recorder_note(info: dict[str, Any]) -> str:
    """Beside the gaps read from the file's sequence numbers, the recorder's own count when the
    two differ (a file that does not say which publisher wrote a message is read by inference;
    a session split into several files is counted whole by the recorder)."""
    rec = info.get("recorder_gaps")
    if rec is None or rec == info["gaps"]:
        return ""
    return f" (the recorder counted {rec} for its session, per publisher)"


def _topic_table(topics: dict[str, dict[str, Any]]) -> list[str]:
    """The per-topic table, each column as wide as its widest entry (a large count never runs
    into its neighbour)."""
    head = ["topic", "type", "count", "rate Hz", "expected", "MiB", "seq gaps", "time gaps", "gap s", "longest s"]
    rows = [
        [
            t,
            ti["type"],
            str(ti["count"]),
            f"{ti['rate_hz']:.2f}",
            f"{ti.get('expected_hz', 0.0):.2f}",
            f"{ti['bytes'] / 2**20:.2f}",
            str(ti["gaps"]),
            str(ti.get("time_gaps", 0)),
            f"{ti.get('time_gap_s', 0.0):.2f}",
            f"{ti.get('longest_gap_s', 0.0):.2f}",
        ]
        for t, ti in topics.items()
    ]
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]

    def line(cells: list[str]) -> str:
        return "  ".join(
            c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    return [line(head), *(line(r) for r in rows)]
