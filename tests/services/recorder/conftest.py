"""A recorder served in this process on a loopback bus, with its seams reachable."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from services.recorder.app import serve
from services.recorder.config import RecorderConfig
from tiplog import topics
from tiplog.bus import Bus
from tiplog.v1 import recorder_pb2


@dataclass
class StatusWatch:
    """Every recorder/status seen; wait for one that satisfies a predicate."""

    items: list[recorder_pb2.RecorderStatus] = field(default_factory=list)
    cv: threading.Condition = field(default_factory=threading.Condition)

    def __call__(self, msg: recorder_pb2.RecorderStatus, _info: Any) -> None:
        with self.cv:
            self.items.append(msg)
            self.cv.notify_all()

    def wait(self, pred: Callable[[recorder_pb2.RecorderStatus], bool], timeout: float = 20.0):
        with self.cv:
            ok = self.cv.wait_for(lambda: any(pred(s) for s in self.items), timeout)
            last = self.items[-1] if self.items else None
        assert ok, f"no matching recorder/status in {timeout} s; last: {last}"
        return next(s for s in reversed(self.items) if pred(s))


@dataclass
class Served:
    bus: Bus  # a second session, connected to the recorder's
    status: StatusWatch
    thread: threading.Thread
    stop: threading.Event
    result: list

    def command(self, action: int, reason: str = "", session: str = "") -> recorder_pb2.RecorderReply:
        cmd = recorder_pb2.RecorderCommand(action=action, reason=reason, session=session)
        (raw,) = self.bus.request(topics.RECORDER_COMMAND, cmd.SerializeToString(), timeout_s=10.0)
        return recorder_pb2.RecorderReply.FromString(raw)


@pytest.fixture
def served_recorder(bus_pair_configs, tmp_path) -> Iterator[Callable[..., Served]]:
    """Factory: served_recorder(opener=..., disk_usage=..., **config fields) -> Served."""
    listen_cfg, connect_cfg = bus_pair_configs
    opened: list[tuple[Bus, Bus, threading.Thread, threading.Event]] = []

    def make(**kw: Any) -> Served:
        seams = {k: kw.pop(k) for k in ("opener", "disk_usage") if k in kw}
        base = dict(out_dir=str(tmp_path / "rec"), autostart="never", min_free_bytes=0, status_period_s=0.1)
        base.update(kw)
        cfg = RecorderConfig(bus=listen_cfg, **base)
        rec_bus = Bus(listen_cfg, service="recorder")
        stop, ready = threading.Event(), threading.Event()
        result: list = []
        t = threading.Thread(target=lambda: result.append(serve(rec_bus, cfg, stop, ready=ready, **seams)), daemon=True)
        t.start()
        assert ready.wait(20)
        client = Bus(connect_cfg)
        watch = StatusWatch()
        client.subscribe("recorder/status", watch)
        watch.wait(lambda s: True)  # the two sessions see each other
        opened.append((client, rec_bus, t, stop))
        return Served(client, watch, t, stop, result)

    yield make
    for client, rec_bus, t, stop in opened:
        stop.set()
        t.join(30)
        client.close()
        rec_bus.close()
