"""What a recording holds: duration, topics, types, rates, counts, sequence gaps, metadata.

Gaps come from the MCAP `sequence` field (the publisher's bus sequence number): a forward
jump of more than one on a topic counts the samples in between as lost upstream; a jump
backwards starts a new publisher (a restarted service) and counts nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.stream_reader import StreamReader

from tiplog.mcap_check import DamagedRecord, metadata_records
from tiplog.mcap_io import open_reader

NS_PER_S = 1_000_000_000


@dataclass
class TopicInfo:
    topic: str
    type_name: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    gaps: int = 0  # samples missing according to the sequence numbers
    gap_events: int = 0
    bytes: int = 0
    _last_seq: int | None = field(default=None, repr=False)

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
        last = self._last_seq
        if last is not None and seq > last + 1:
            self.gaps += seq - last - 1
            self.gap_events += 1
        self._last_seq = seq

    def as_dict(self) -> dict[str, Any]:
        return {
            "type": self.type_name,
            "count": self.count,
            "rate_hz": round(self.rate_hz, 3),
            "first_ns": self.first_ns,
            "last_ns": self.last_ns,
            "bytes": self.bytes,
            "gaps": self.gaps,
            "gap_events": self.gap_events,
        }


def inspect(path: str | Path) -> dict[str, Any]:
    """Everything `tiplog info` shows, as a JSON-ready dict."""
    path = Path(path)
    topics: dict[int, TopicInfo] = {}
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
                ti = topics.get(channel.id)
                if ti is None:
                    ti = topics[channel.id] = TopicInfo(channel.topic, schema.name if schema else "")
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
    by_topic: dict[str, TopicInfo] = {}
    for ti in topics.values():  # one topic may have several channels (several writers)
        by_topic.setdefault(ti.topic, ti)
    firsts = [t.first_ns for t in by_topic.values() if t.first_ns is not None]
    lasts = [t.last_ns for t in by_topic.values() if t.last_ns is not None]
    start, end = (min(firsts), max(lasts)) if firsts else (None, None)
    return {
        "file": str(path),
        "bytes": path.stat().st_size,
        "indexed": indexed,
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) / NS_PER_S if start is not None and end is not None else 0.0,
        "messages": sum(t.count for t in by_topic.values()),
        "gaps": sum(t.gaps for t in by_topic.values()),
        "topics": {t: ti.as_dict() for t, ti in sorted(by_topic.items())},
        "metadata": metadata,
        "attachments": attachments,
    }


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
        f"messages:  {info['messages']}   gaps (from sequence): {info['gaps']}",
        "",
        f"{'topic':<22}{'type':<36}{'count':>9}{'rate Hz':>10}{'MiB':>9}{'gaps':>7}",
    ]
    for t, ti in info["topics"].items():
        out.append(
            f"{t:<22}{ti['type']:<36}{ti['count']:>9}{ti['rate_hz']:>10.2f}{ti['bytes'] / 2**20:>9.2f}{ti['gaps']:>7}"
        )
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
