"""`python -m services.recorder`: records every topic under the prefix into MCAP files.

Listens on `recorder/command` (RecorderCommand -> RecorderReply), publishes `recorder/status`
at `status_period_s` and on every state change. See `services.recorder.recorder` for times,
crash safety and the full-disk behaviour.
"""

from __future__ import annotations

import logging
import shutil
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from services.recorder.config import RecorderConfig
from services.recorder.mcap_file import Opener, open_file
from services.recorder.recorder import STATUS_TOPIC, DiskUsage, Recorder
from tiplog import topics
from tiplog.bus import Bus, SampleInfo
from tiplog.config import dump
from tiplog.service import ServiceContext, run_service
from tiplog.v1 import recorder_pb2

NAME = "recorder"
log = logging.getLogger("tiplog.recorder")

__all__ = ["NAME", "RecorderConfig", "main", "serve"]


def serve(
    bus: Bus,
    config: RecorderConfig,
    stop: threading.Event,
    *,
    opener: Opener = open_file,
    disk_usage: DiskUsage = shutil.disk_usage,
    ready: threading.Event | None = None,
    config_file: str | None = None,
) -> Recorder:
    """Run a recorder on `bus` until `stop` is set; returns it (finished) for inspection."""
    status_pub = bus.publisher(STATUS_TOPIC)
    status_lock = threading.Lock()

    def publish_status(st: recorder_pb2.RecorderStatus) -> None:
        with status_lock:
            status_pub.put(st)

    attachments = {}
    if config_file:  # the system's YAML file as given, beside the resolved recorder section
        attachments[Path(config_file).name] = (Path(config_file).read_bytes(), "application/yaml")
    rec = Recorder(
        config,
        opener=opener,
        disk_usage=disk_usage,
        on_status=publish_status,
        extra_metadata={"bus": {"prefix": bus.prefix, "bus_config": dump(bus.config)}},
        extra_attachments=attachments,
    )

    def on_command(query: zenoh.Query) -> None:
        try:
            raw = query.payload.to_bytes() if query.payload is not None else b""
            cmd = recorder_pb2.RecorderCommand.FromString(raw)
        except Exception as e:
            query.reply_err(f"not a RecorderCommand: {e}".encode())
            return
        reply = rec.command(cmd)
        query.reply(query.key_expr, reply.SerializeToString())

    # Subscribed before the writer starts: the first RECORDING status means the subscription
    # is already declared (a publisher that sees it may start at once).
    exact = {t for t in config.exclude_topics if not t.endswith("/")}
    prefixes = tuple(t for t in config.exclude_topics if t.endswith("/"))

    def on_sample(payload: bytes, info: SampleInfo) -> None:
        if info.topic in exact or (prefixes and info.topic.startswith(prefixes)):
            return
        rec.on_sample(payload, info)

    bus.subscribe_raw(config.key_expr, on_sample if config.exclude_topics else rec.on_sample)
    rec.start_thread()
    bus.queryable(topics.RECORDER_COMMAND, on_command)
    publish_status(rec.status())
    if ready is not None:
        ready.set()
    while not stop.wait(config.status_period_s):
        publish_status(rec.status())
    rec.close()
    publish_status(rec.status())
    return rec


def _body(ctx: ServiceContext[RecorderConfig]) -> None:
    serve(ctx.bus, ctx.config, ctx.stop, config_file=getattr(ctx.args, "config", None))


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, RecorderConfig, _body, argv, description=__doc__)
