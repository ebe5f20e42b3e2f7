"""Foxglove live: the bus's topics, with their protobuf schemas, on a Foxglove WebSocket server
(the `foxglove-sdk` package), so the Foxglove app pointed at ws://<cart>:8765 shows images,
transforms and plots live. Off by default (`dashboard.foxglove_bridge: true` turns it on).

Each topic becomes a channel on its first message, named as on the bus without the prefix
(`fusion/state`), with the message's full protobuf name and a FileDescriptorSet holding it
and its dependencies. Payloads are relayed as received (no re-encoding). The SDK buffers
per client and drops the oldest for a slow one; nothing here waits on a client. Messages are
logged with the wall clock (Foxglove shows calendar time), the host stamps stay in headers.

The Foxglove protocol has no authentication: it binds to loopback by default, and to any
other address only with `foxglove_allow_remote: true` (a trusted network, or behind a proxy).
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import foxglove
from mcap_protobuf.schema import build_file_descriptor_set

from services.dashboard.config import DashboardConfig
from tiplog import topics
from tiplog.bus import Bus, SampleInfo
from tiplog.clock import wall_ns
from tiplog.userio import UserError

log = logging.getLogger("tiplog.dashboard.foxglove")


class FoxgloveBridge:
    """Relays raw bus payloads to Foxglove channels, one per topic."""

    def __init__(self, bus: Bus, server: Any, context: foxglove.Context, key_expr: str):
        self.bus = bus
        self.server = server
        self.context = context
        self.port: int = server.port
        self.relayed = 0
        self.unknown_type = 0
        self.skipped = 0  # payloads no Foxglove client subscribed to: never copied
        self._channels: dict[str, tuple[foxglove.Channel, str]] = {}
        self._schemas: dict[str, foxglove.Schema] = {}
        self._lock = threading.Lock()
        self._sub = bus.subscribe_raw(key_expr, self._on_sample, want=self._wanted)

    @classmethod
    def start(cls, bus: Bus, config: DashboardConfig) -> FoxgloveBridge:
        """Start the WebSocket server on `foxglove_host:foxglove_port` and subscribe; UserError
        for a non-loopback address without `foxglove_allow_remote`."""
        problem = config.foxglove_binding_problem()
        if problem:
            raise UserError(problem)
        context = foxglove.Context()
        server = foxglove.start_server(
            name="tiplog", host=config.foxglove_host, port=config.foxglove_port, context=context
        )
        bridge = cls(bus, server, context, config.foxglove_topics)
        log.info("Foxglove bridge on ws://%s:%d (topics %s)", config.foxglove_host, bridge.port, config.foxglove_topics)
        return bridge

    def _schema(self, type_name: str) -> foxglove.Schema | None:
        schema = self._schemas.get(type_name)
        if schema is None:
            try:
                cls = topics.message_class_by_name(type_name)
            except KeyError:
                return None
            data = build_file_descriptor_set(cls).SerializeToString()
            schema = self._schemas[type_name] = foxglove.Schema(name=type_name, encoding="protobuf", data=data)
        return schema

    def _channel(self, topic: str, type_name: str) -> foxglove.Channel | None:
        with self._lock:
            known = self._channels.get(topic)
            if known is not None:
                return known[0] if known[1] == type_name else None
            schema = self._schema(type_name)
            if schema is None:
                return None
            ch = foxglove.Channel(topic, schema=schema, message_encoding="protobuf", context=self.context)
            self._channels[topic] = (ch, type_name)
            return ch

    def _wanted(self, info: SampleInfo) -> bool:
        """A payload is copied out only for a channel a Foxglove client subscribes to (or one
        not yet advertised): with no client, the camera's frames cost the dashboard nothing."""
        known = self._channels.get(info.topic)
        if known is None or known[0].has_sinks():
            return True
        self.skipped += 1
        return False

    def _on_sample(self, payload: bytes, info: SampleInfo) -> None:
        ch = self._channel(info.topic, info.type_name) if info.type_name else None
        if ch is None:
            self.unknown_type += 1
            if self.unknown_type <= 5:
                log.warning("not relayed to Foxglove: %s carries %r", info.topic, info.type_name or "no type")
            return
        ch.log(payload, log_time=wall_ns())
        self.relayed += 1

    def stop(self) -> None:
        self._sub.close()
        self.server.stop()
