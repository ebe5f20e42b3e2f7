"""What the recorder lets into a topic's channel: a payload that decodes as the topic's type.

A channel of an MCAP file has one schema, and every reader decodes every message of it with
that schema: one payload that does not parse makes `read_messages` (and Foxglove) fail on the
whole file. So before a payload is written, `Admission.check` decides, cheaply, whether it is
a well-formed message of the type its topic carries:

1. The type: on a topic of `tiplog.topics.TOPICS` the attachment must name exactly that
   topic's type (`wrong_type` otherwise; `no_type` for a payload without a tiplog attachment).
   On another topic the attachment's type must be a schema this build knows (`unknown_type`).
2. The bytes parse as that type (`undecodable` otherwise). upb parses in C; a 2.7 MB camera
   frame costs about one memory copy (measured: 0.07 ms, against ~3 ms to lz4-compress it).
3. Protobuf parses leniently: another type's bytes, or short garbage, often parse without an
   error, their fields landing in the message's unknown fields (a field number the schema
   lacks, or a known number with another wire type). A payload with unknown top-level fields
   is rejected (`unknown_fields`). Publishers and recorder share one schema build
   (`tiplog.v1`); a newer publisher's added fields would be rejected here too, but kept in
   the quarantine, not lost.
4. An empty or near-empty payload parses as a message with every field at its default. Every
   stream message of the system is stamped: the type's `header` (tiplog) or `timestamp`
   (Foxglove images and calibrations) must be present (`no_stamp`). Types with neither
   (FrameTransforms) skip this test.

Rejected payloads are counted per topic and reason, and kept (`quarantine_record`) on the
channel `_rejected/<topic>:<reason>` as `google.protobuf.Any` (type_url naming the claimed
type, value the payload bytes unchanged): a schema every reader decodes, so the file stays
readable as a whole, and nothing is lost.
"""

from __future__ import annotations

from dataclasses import dataclass

from google.protobuf import any_pb2
from google.protobuf.message import DecodeError, Message
from google.protobuf.unknown_fields import UnknownFieldSet

from tiplog import topics

QUARANTINE_PREFIX = "_rejected/"
QUARANTINE_TYPE = "google.protobuf.Any"
TYPE_URL_PREFIX = "type.googleapis.com/"
REASONS = ("no_type", "wrong_type", "unknown_type", "undecodable", "unknown_fields", "no_stamp")


def quarantine_topic(topic: str, reason: str) -> str:
    """Channel of the payloads of `topic` rejected for `reason`."""
    return f"{QUARANTINE_PREFIX}{topic}:{reason}"


def quarantine_record(type_name: str, payload: bytes) -> bytes:
    """A serialised `google.protobuf.Any{type_url, value=payload}` (rejections are rare: the
    extra copy protobuf makes does not matter)."""
    return any_pb2.Any(type_url=TYPE_URL_PREFIX + type_name, value=payload).SerializeToString()


@dataclass(frozen=True, slots=True)
class _Expect:
    cls: type[Message]
    name: str
    stamp_field: str | None  # "header", "timestamp" or None


def _expect(cls: type[Message]) -> _Expect:
    fields = cls.DESCRIPTOR.fields_by_name
    stamp = next((f for f in ("header", "timestamp") if f in fields), None)
    return _Expect(cls, cls.DESCRIPTOR.full_name, stamp)


class Admission:
    """The check of one recorder; call from one thread (the writer's). Per-topic expectations
    are cached: after the first message of a topic a check is a dict look-up and a parse."""

    def __init__(self) -> None:
        self._known: dict[str, _Expect] = {t: _expect(c) for t, c in topics.TOPICS.items()}
        self._by_name: dict[str, _Expect | None] = {}  # other topics: by the claimed type

    def check(self, topic: str, type_name: str, payload: bytes) -> str | None:
        """None when `payload` may be written on `topic` as `type_name`, else the reason."""
        exp = self._known.get(topic)
        if not type_name:
            return "no_type"
        if exp is None:
            if type_name not in self._by_name:
                try:
                    self._by_name[type_name] = _expect(topics.message_class_by_name(type_name))
                except KeyError:
                    self._by_name[type_name] = None
            exp = self._by_name[type_name]
            if exp is None:
                return "unknown_type"
        elif type_name != exp.name:
            return "wrong_type"
        try:
            msg = exp.cls.FromString(payload)
        except (DecodeError, ValueError, RuntimeError):
            return "undecodable"
        if len(UnknownFieldSet(msg)):
            return "unknown_fields"
        if exp.stamp_field is not None and not msg.HasField(exp.stamp_field):
            return "no_stamp"
        return None
