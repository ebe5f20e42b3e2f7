"""Rebuild a valid, indexed MCAP file from a truncated or damaged one.

Records are read in file order with mcap's stream reader until the first one that is cut
off or fails its CRC; everything before it (schemas, channels, messages, metadata,
attachments) is written again into a fresh file with a summary. A chunk whose CRC or
decompression fails is the truncation point: nothing after it is trusted.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from tiplog.mcap_io import LIBRARY, PROFILE
from tiplog.mcap_salvage import Salvage, intact_records

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}


@dataclass
class RecoveryReport:
    """What was kept and what was lost; times are log times in ns."""

    source: str
    output: str
    source_bytes: int = 0
    good_bytes: int = 0  # the prefix of the source that was read completely
    messages_by_topic: Counter = field(default_factory=Counter)
    metadata: int = 0
    attachments: int = 0
    first_log_ns: int | None = None
    last_good_log_ns: int | None = None
    complete: bool = False  # the source's data section ended in order: nothing was lost
    error: str = ""

    @property
    def messages(self) -> int:
        return sum(self.messages_by_topic.values())

    @property
    def lost_bytes(self) -> int:
        return self.source_bytes - self.good_bytes

    def as_dict(self) -> dict:
        return {
            "source": self.source,
            "output": self.output,
            "source_bytes": self.source_bytes,
            "good_bytes": self.good_bytes,
            "lost_bytes": self.lost_bytes,
            "messages": self.messages,
            "messages_by_topic": dict(sorted(self.messages_by_topic.items())),
            "metadata": self.metadata,
            "attachments": self.attachments,
            "first_log_ns": self.first_log_ns,
            "last_good_log_ns": self.last_good_log_ns,
            "complete": self.complete,
            "error": self.error,
        }


def recover(source: str | Path, output: str | Path, *, compression: str = "lz4") -> RecoveryReport:
    """Copy every intact record of `source` into a new indexed file at `output`."""
    source, output = Path(source), Path(output)
    if source.resolve() == output.resolve():
        raise ValueError("output must differ from the source file")
    rep = RecoveryReport(str(source), str(output), source_bytes=source.stat().st_size)
    state = Salvage(source_bytes=rep.source_bytes)
    with open(source, "rb") as fin, open(output, "wb") as fout:
        w = Writer(
            fout,
            compression=CompressionType.LZ4
            if compression == "lz4"
            else _COMPRESSION.get(compression, CompressionType.ZSTD),
            enable_data_crcs=True,
        )
        w.start(profile=PROFILE, library=LIBRARY)
        schema_map: dict[int, int] = {}
        channel_map: dict[int, int] = {}
        channel_topic: dict[int, str] = {}

        def handle(rec: object) -> None:
            if isinstance(rec, Schema):
                if rec.id not in schema_map:
                    schema_map[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id not in channel_map:
                    _register_channel(rec)
            elif isinstance(rec, Message):
                cid = channel_map.get(rec.channel_id)
                if cid is None:
                    return
                w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
                rep.messages_by_topic[channel_topic[rec.channel_id]] += 1
                if rep.first_log_ns is None or rec.log_time < rep.first_log_ns:
                    rep.first_log_ns = rec.log_time
                if rep.last_good_log_ns is None or rec.log_time > rep.last_good_log_ns:
                    rep.last_good_log_ns = rec.log_time
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, rec.metadata)
                rep.metadata += 1
            elif isinstance(rec, Attachment):
                w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
                rep.attachments += 1

        def _register_channel(ch: Channel) -> None:
            sid = schema_map.get(ch.schema_id, 0) if ch.schema_id else 0
            if ch.schema_id and not sid:
                return  # its schema was never written: its messages cannot be decoded
            channel_map[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
            channel_topic[ch.id] = ch.topic

        for rec in intact_records(fin, state):
            handle(rec)
        w.finish()
    rep.good_bytes, rep.complete, rep.error = state.good_bytes, state.complete, state.error
    if rep.complete:
        rep.good_bytes = rep.source_bytes
    return rep
