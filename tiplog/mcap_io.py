"""MCAP files of protobuf messages: the one writer and reader every part uses.

Times are int64 ns. Schemas (a FileDescriptorSet with all dependencies) and channels are
registered lazily on the first message of a topic; a later message of another type on the
same topic is an error. Offline sessions from the bench, recordings from the recorder and
offline fusion runs are all written through `McapWriter`, so any of them opens in Foxglove
and in other MCAP readers.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from google.protobuf.message import Message
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as _Writer
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import build_file_descriptor_set

from tiplog import __version__, topics

PROFILE = ""  # protobuf-encoded channels; no ROS profile
LIBRARY = f"tiplog/{__version__}"


class McapWriter:
    """Protobuf messages into one MCAP file (path or binary stream).

    `flush()` closes the chunk in progress and flushes the stream: everything before it is
    readable from the file even if the process dies before `close()`.
    """

    def __init__(
        self,
        output: str | Path | IO[bytes],
        *,
        compression: str = "zstd",
        chunk_size: int = 4 * 1024 * 1024,
    ):
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in comp:
            raise ValueError(f"compression must be one of {', '.join(comp)} (got {compression!r})")
        self._own = isinstance(output, (str, Path))
        self._stream: IO[bytes] = open(output, "wb") if self._own else output  # noqa: SIM115
        self._w = _Writer(self._stream, chunk_size=chunk_size, compression=comp[compression])
        self._w.start(profile=PROFILE, library=LIBRARY)
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self.message_count = 0
        self._closed = False

    def _channel(self, topic: str, type_name: str, msg_class: type[Message] | None) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise ValueError(f"topic {topic!r} carries {known[1]}; cannot write a {type_name}")
            return known[0]
        if type_name not in self._schema_ids:
            cls = msg_class or topics.message_class_by_name(type_name)
            fds = build_file_descriptor_set(cls)
            self._schema_ids[type_name] = self._w.register_schema(
                name=type_name, encoding=SchemaEncoding.Protobuf, data=fds.SerializeToString()
            )
        cid = self._w.register_channel(
            topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=self._schema_ids[type_name]
        )
        self._channels[topic] = (cid, type_name)
        return cid

    def write(
        self, topic: str, msg: Message, log_time_ns: int, publish_time_ns: int | None = None, sequence: int = 0
    ) -> None:
        """Append one message; `log_time_ns` is its time on the session's clock."""
        cid = self._channel(topic, msg.DESCRIPTOR.full_name, type(msg))
        self._add(cid, msg.SerializeToString(), log_time_ns, publish_time_ns, sequence)

    def write_raw(
        self,
        topic: str,
        type_name: str,
        payload: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
        sequence: int = 0,
    ) -> None:
        """Append an already serialised message of protobuf type `type_name`."""
        cid = self._channel(topic, type_name, None)
        self._add(cid, payload, log_time_ns, publish_time_ns, sequence)

    def _add(self, cid: int, data: bytes, log_time_ns: int, publish_time_ns: int | None, sequence: int) -> None:
        self._w.add_message(
            channel_id=cid,
            log_time=int(log_time_ns),
            data=data,
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=int(sequence) & 0xFFFFFFFF,
        )
        self.message_count += 1

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """Metadata record; non-string values are stored as JSON."""
        self._w.add_metadata(name, {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()})

    def add_attachment(
        self, name: str, data: bytes, media_type: str = "application/octet-stream", log_time_ns: int = 0
    ) -> None:
        self._w.add_attachment(
            create_time=log_time_ns, log_time=log_time_ns, name=name, media_type=media_type, data=data
        )

    def flush(self) -> None:
        self._w.flush()

    def close(self) -> None:
        """Write the summary (indexes, statistics) and close the file."""
        if self._closed:
            return
        self._closed = True
        self._w.finish()
        if self._own:
            self._stream.close()

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True, slots=True)
class Record:
    topic: str
    message: Any  # decoded protobuf message
    log_time_ns: int
    publish_time_ns: int
    sequence: int


def _decoder_for(schema_name: str, schema_data: bytes, cache: dict, factory: DecoderFactory, schema: Any) -> Any:
    dec = cache.get(schema_name)
    if dec is None:
        try:
            cls = topics.message_class_by_name(schema_name)
            dec = cls.FromString
        except KeyError:  # a schema this build does not know: decode from the embedded one
            dec = factory.decoder_for(MessageEncoding.Protobuf, schema)
        cache[schema_name] = dec
    return dec


def read_messages(path: str | Path | IO[bytes], topics_: Iterable[str] | None = None) -> Iterator[Record]:
    """Decoded messages in log-time order (all topics, or only `topics_`)."""
    own = isinstance(path, (str, Path))
    stream = open(path, "rb") if own else path  # noqa: SIM115
    try:
        reader = make_reader(stream)
        cache: dict[str, Any] = {}
        factory = DecoderFactory()
        wanted = list(topics_) if topics_ is not None else None
        for schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
            dec = _decoder_for(schema.name, schema.data, cache, factory, schema)
            yield Record(channel.topic, dec(message.data), message.log_time, message.publish_time, message.sequence)
    finally:
        if own:
            stream.close()


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """All metadata records by name (a later record of the same name wins)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        return {m.name: dict(m.metadata) for m in reader.iter_metadata()}


def read_attachments(path: str | Path) -> dict[str, bytes]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        return {a.name: a.data for a in reader.iter_attachments()}


def read_summary(path: str | Path) -> Any:
    """The file's summary (statistics, channels, schemas), or None for an unindexed file."""
    with open(path, "rb") as f:
        return make_reader(f).get_summary()
