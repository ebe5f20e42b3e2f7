"""The Zenoh bus: one session per process, typed publishers and subscribers, liveliness.

Every payload is a serialised protobuf message. Each put carries a small attachment,
`<u64 seq><i64 publish_ns><u32 publisher_id><message full name utf-8>`, so that any
subscriber (the recorder above all) can count gaps per publisher and decode topics it has
never heard of. A payload that does not decode is counted and logged, never raised into the
subscriber's callback: one corrupt message must not take a service down.
"""

from __future__ import annotations

import logging
import queue
import random
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import zenoh
from google.protobuf.message import DecodeError, Message

from tiplog import topics
from tiplog.bus_config import DEFAULT_ENDPOINT, BusConfig
from tiplog.clock import now_ns

__all__ = ["DEFAULT_ENDPOINT", "Bus", "BusConfig", "Publisher", "SampleInfo", "Subscriber"]

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

_ATTACH = struct.Struct("<QqI")
# How long a process may look for its router before it says, in one line, that none answers.
NOTICE_AFTER_S = 2.0


def no_router_line(endpoints: list[str]) -> str:
    """The one line a process logs when no router answers at `endpoints`."""
    eps = ", ".join(endpoints) or "(no endpoint)"
    return (
        f"bus: no router answers at {eps}; start one with `tiplog up` (the whole system) or "
        f"`python -m tiplog.router --listen {endpoints[0] if endpoints else DEFAULT_ENDPOINT}`; still trying"
    )


def alone_line(endpoint: str) -> str:
    """The one line a standalone process logs when no router answers, it listens there itself and
    nothing has joined it."""
    return (
        f"bus: no router answers at {endpoint}; listening there alone, so only tiplog processes started "
        f"alone on this machine (`tiplog record run`) reach this one; for the system start a router with "
        f"`tiplog up` or `python -m tiplog.router --listen {endpoint}`"
    )


def _loopback_tcp(endpoints: list[str]) -> str | None:
    for e in endpoints:
        if e.startswith(("tcp/127.", "tcp/localhost:", "tcp/[::1]:")):
            return e
    return None


@dataclass(frozen=True, slots=True)
class SampleInfo:
    """What the bus knows about a received message besides its payload."""

    topic: str  # without prefix
    seq: int  # per-publisher sequence number, from 0
    publish_ns: int  # publisher's host clock at put
    receive_ns: int  # this host's clock on arrival
    publisher_id: int
    type_name: str


def encode_attachment(seq: int, publish_ns: int, publisher_id: int, type_name: str) -> bytes:
    return _ATTACH.pack(seq, publish_ns, publisher_id) + type_name.encode()


def decode_attachment(raw: bytes | None) -> tuple[int, int, int, str]:
    """(seq, publish_ns, publisher_id, type_name); zeros and '' for a foreign publisher."""
    if raw is None or len(raw) < _ATTACH.size:
        return 0, 0, 0, ""
    seq, pub_ns, pid = _ATTACH.unpack_from(raw)
    return seq, pub_ns, pid, raw[_ATTACH.size :].decode(errors="replace")


def _sample_info(bus: Bus, sample: zenoh.Sample) -> SampleInfo:
    recv = now_ns()
    att = sample.attachment
    seq, pub_ns, pid, type_name = decode_attachment(att.to_bytes() if att is not None else None)
    return SampleInfo(bus.topic_of(str(sample.key_expr)), seq, pub_ns, recv, pid, type_name)


class _Closing:
    """Context manager calling close() on exit."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Publisher(_Closing, Generic[M]):
    """Typed publisher for one topic. `put(msg)` serialises and sends."""

    def __init__(self, bus: Bus, topic: str, msg_type: type[M], reliable: bool):
        self.topic = topic
        self.msg_type = msg_type
        self._type_name = msg_type.DESCRIPTOR.full_name
        self._id = random.getrandbits(32)
        self._seq = 0
        self._lock = threading.Lock()
        cc = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
        self._pub = bus.session.declare_publisher(bus.key(topic), congestion_control=cc)

    def put(self, msg: M) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.topic} carries {self._type_name}, got {type(msg).__name__}")
        self.put_bytes(msg.SerializeToString())

    def put_bytes(self, payload: bytes) -> None:
        """Send an already serialised payload of this topic's type (replay, relays)."""
        with self._lock:
            seq = self._seq
            self._seq += 1
        att = encode_attachment(seq, now_ns(), self._id, self._type_name)
        self._pub.put(payload, attachment=att)

    def close(self) -> None:
        self._pub.undeclare()


class Subscriber(_Closing, Generic[M]):
    """Typed subscriber. With a callback, it is called on Zenoh's thread with
    `(msg, info)`: keep it short. Without one, messages queue (bounded, oldest dropped and
    counted) and `recv()` takes them on the caller's thread."""

    def __init__(
        self,
        bus: Bus,
        key_expr: str,
        msg_type: type[M] | None,
        callback: Callable[[M, SampleInfo], None] | None,
        maxsize: int,
    ):
        self._bus = bus
        self._msg_type = msg_type
        self._callback = callback
        self._queue: queue.Queue[tuple[M, SampleInfo]] | None = None if callback else queue.Queue(maxsize=maxsize)
        self.received = 0
        self.decode_errors = 0
        self.queue_drops = 0
        self._sub = bus.session.declare_subscriber(bus.key(key_expr), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        info = _sample_info(self._bus, sample)
        topic, type_name = info.topic, info.type_name
        try:
            # A payload without a tiplog attachment, or naming another type, is as undecodable
            # as a corrupt one: a protobuf parser accepts many random byte strings.
            if not type_name:
                raise ValueError("no tiplog attachment (foreign publisher?)")
            if self._msg_type is not None and type_name != self._msg_type.DESCRIPTOR.full_name:
                raise ValueError(f"carries {type_name}, expected {self._msg_type.DESCRIPTOR.full_name}")
            msg_type = self._msg_type or topics.message_class_by_name(type_name)
            msg = msg_type.FromString(sample.payload.to_bytes())
        except (DecodeError, KeyError, ValueError, RuntimeError) as e:
            self.decode_errors += 1
            if self.decode_errors <= 10 or self.decode_errors % 1000 == 0:
                log.warning("undecodable payload on %s (%d so far): %s", topic, self.decode_errors, e)
            return
        self.received += 1
        if self._callback is not None:
            try:
                self._callback(msg, info)
            except Exception:  # a subscriber bug must not kill Zenoh's thread
                log.exception("subscriber callback for %s raised", topic)
            return
        assert self._queue is not None
        try:
            self._queue.put_nowait((msg, info))
        except queue.Full:
            self.queue_drops += 1
            try:
                self._queue.get_nowait()
            except queue.Empty:
                pass
            self._queue.put_nowait((msg, info))

    def recv(self, timeout: float | None = None) -> tuple[M, SampleInfo] | None:
        """Next (message, info), or None after `timeout` seconds."""
        if self._queue is None:
            raise RuntimeError("this subscriber delivers to its callback")
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._sub.undeclare()


class RawSubscriber(_Closing):
    """Undecoded payloads with their info, for the recorder: `callback(payload, info)`; with
    `want`, only for the samples whose info it accepts (the others' payloads are never copied
    out of Zenoh: a camera frame is megabytes)."""

    def __init__(
        self,
        bus: Bus,
        key_expr: str,
        callback: Callable[[bytes, SampleInfo], None],
        want: Callable[[SampleInfo], bool] | None = None,
    ):
        self._bus = bus
        self._callback = callback
        self._want = want
        self._sub = bus.session.declare_subscriber(bus.key(key_expr), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        info = _sample_info(self._bus, sample)
        try:
            if self._want is not None and not self._want(info):
                return
            self._callback(sample.payload.to_bytes(), info)
        except Exception:
            log.exception("raw subscriber callback for %s raised", info.topic)

    def close(self) -> None:
        self._sub.undeclare()


class Bus:
    """One Zenoh session with the tiplog key prefix. Use as a context manager: the session
    and everything declared on it is closed on exit (an unclosed queryable hangs exit)."""

    def __init__(
        self, config: BusConfig | None = None, service: str | None = None, stop: threading.Event | None = None
    ):
        self.config = config or BusConfig()
        self.prefix = self.config.prefix
        self.service = service
        self._watch_stop = threading.Event()
        self.session = self._open(stop)
        self._declared: list[Any] = []
        self._closed = False
        if service:
            self._declared.append(self.session.liveliness().declare_token(self.key(f"{topics.ALIVE}/{service}")))

    def _open(self, stop: threading.Event | None) -> zenoh.Session:
        cfg = self.config
        self.holds_endpoint: str | None = None
        ep = _loopback_tcp(cfg.connect) if cfg.mode == "peer" and cfg.standalone else None
        if ep is not None:
            alone = cfg.model_copy(update={"listen": [*cfg.listen, ep], "connect": [e for e in cfg.connect if e != ep]})
            try:
                session = zenoh.open(alone.zenoh_config())
            except zenoh.ZError:  # a router (or another standalone process) holds it: join it
                pass
            else:
                self.holds_endpoint = ep
                log.debug(
                    "bus: no router at %s: listening there, so tiplog processes on this machine find this one "
                    "(`tiplog up` runs the whole system)",
                    ep,
                )
                threading.Thread(
                    target=self._watch_alone, args=(session, ep), name="bus-alone-watch", daemon=True
                ).start()
                return session
        t0 = time.monotonic()
        deadline = None if cfg.open_timeout_s is None else t0 + cfg.open_timeout_s
        delay = 0.1
        warned = False
        while True:
            try:
                session = zenoh.open(cfg.zenoh_config())
            except zenoh.ZError as e:
                if deadline is not None and time.monotonic() + delay > deadline:
                    raise ConnectionError(
                        f"bus: no router answered at {', '.join(cfg.connect) or '(no endpoint)'} "
                        f"within {cfg.open_timeout_s:g} s ({e})"
                    ) from None
                if not warned and time.monotonic() - t0 + delay >= NOTICE_AFTER_S:
                    log.warning("%s", no_router_line(cfg.connect))
                    warned = True
                else:
                    log.debug("bus: waiting for %s (%s)", ", ".join(cfg.connect), str(e).split(" at ")[0])
                if stop is not None and stop.wait(delay):
                    raise ConnectionError("bus: stopped while waiting for the router") from None
                if stop is None:
                    time.sleep(delay)
                delay = min(2.0, delay * 2)
                continue
            if cfg.mode == "peer" and cfg.connect:
                threading.Thread(
                    target=self._watch_router, args=(session,), name="bus-router-watch", daemon=True
                ).start()
            return session

    def _watch_alone(self, session: zenoh.Session, endpoint: str) -> None:
        """A standalone process holding the endpoint: when no other process has joined it within
        NOTICE_AFTER_S, say in one line that no router answers (two tiplog processes started
        alone in two terminals meet at once and say nothing)."""
        if self._watch_stop.wait(NOTICE_AFTER_S):
            return
        try:
            joined = bool(list(session.info.peers_zid()) or list(session.info.routers_zid()))
        except Exception:  # the session closed under us
            return
        if not joined:
            log.warning("%s", alone_line(endpoint))

    def _watch_router(self, session: zenoh.Session) -> None:
        """A peer opens at once whether or not its router is there (zenoh keeps trying in the
        background): say so after NOTICE_AFTER_S if nothing is connected, and when it is."""
        if self._watch_stop.wait(NOTICE_AFTER_S):
            return
        warned = False
        while not self._watch_stop.is_set():
            try:
                connected = bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
            except Exception:  # the session closed under us
                return
            if connected:
                if warned:
                    log.info("bus: reached %s", ", ".join(self.config.connect))
                return
            if not warned:
                log.warning("%s", no_router_line(self.config.connect))
                warned = True
            self._watch_stop.wait(1.0)

    # keys -----------------------------------------------------------------
    def key(self, topic: str) -> str:
        return self.prefix + topic

    def topic_of(self, key: str) -> str:
        return key[len(self.prefix) :] if key.startswith(self.prefix) else key

    # declarations ---------------------------------------------------------
    def publisher(self, topic: str, msg_type: type[M] | None = None, *, reliable: bool = True) -> Publisher[M]:
        """Publisher for `topic`; its type comes from the registry unless given."""
        pub = Publisher(self, topic, msg_type or topics.message_type(topic), reliable)
        self._declared.append(pub)
        return pub

    def subscribe(
        self,
        topic: str,
        callback: Callable[[M, SampleInfo], None] | None = None,
        *,
        msg_type: type[M] | None = None,
        maxsize: int = 10_000,
    ) -> Subscriber[M]:
        """Subscriber for `topic` (a key expression without prefix; wildcards decode by the
        attachment's type name when `msg_type` is not given and the topic is not registered)."""
        if msg_type is None and topic in topics.TOPICS:
            msg_type = topics.TOPICS[topic]
        sub = Subscriber(self, topic, msg_type, callback, maxsize)
        self._declared.append(sub)
        return sub

    def subscribe_raw(
        self,
        key_expr: str,
        callback: Callable[[bytes, SampleInfo], None],
        want: Callable[[SampleInfo], bool] | None = None,
    ) -> RawSubscriber:
        sub = RawSubscriber(self, key_expr, callback, want)
        self._declared.append(sub)
        return sub

    def queryable(self, topic: str, handler: Callable[[zenoh.Query], None]) -> Any:
        q = self.session.declare_queryable(self.key(topic), handler)
        self._declared.append(q)
        return q

    def request(self, topic: str, payload: bytes, timeout_s: float = 2.0) -> list[bytes]:
        """Send a query and return the payloads of the successful replies."""
        out: list[bytes] = []
        for reply in self.session.get(self.key(topic), payload=payload, timeout=timeout_s):
            if reply.ok is not None:
                out.append(reply.ok.payload.to_bytes())
            else:
                log.warning("error reply on %s: %s", topic, reply.err.payload.to_bytes()[:200])
        return out

    def alive(self, timeout_s: float = 1.0) -> set[str]:
        """Names of the services whose liveliness tokens are visible now."""
        names = set()
        base = self.key(topics.ALIVE + "/")
        for reply in self.session.liveliness().get(self.key(f"{topics.ALIVE}/**"), timeout=timeout_s):
            if reply.ok is not None:
                names.add(str(reply.ok.key_expr)[len(base) :])
        return names

    def watch_alive(self, callback: Callable[[str, bool], None]) -> Any:
        """Call `callback(service, alive)` on every token appearing or vanishing."""
        base = self.key(topics.ALIVE + "/")

        def on(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr)[len(base) :], sample.kind == zenoh.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(self.key(f"{topics.ALIVE}/**"), on, history=True)
        self._declared.append(sub)
        return sub

    # lifetime -------------------------------------------------------------
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._watch_stop.set()
        for d in reversed(self._declared):
            try:
                if hasattr(d, "close"):
                    d.close()
                else:
                    d.undeclare()
            except Exception as e:  # already undeclared by a failed peer; closing must finish
                log.debug("undeclare failed: %s", e)
        self._declared.clear()
        self.session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
