"""The per-client sender: a slow client gets everything the ring still holds in bounded
batches and then the newest, never a growing queue; the ring's cursors and skips."""

from __future__ import annotations

import asyncio
import json
import threading

import numpy as np
import pytest

from services.dashboard.config import DashboardConfig
from services.dashboard.feed import STATE_COLUMNS
from services.dashboard.ring import Ring
from services.dashboard.streams import Envelope
from services.dashboard.websocket import BatchCache, Wake, serve_client


def test_ring_cursor_and_skip():
    r = Ring(capacity=10, width=2)
    for k in range(25):
        r.append(1000 + k, [k, -k])
    s = r.read(0, 100)  # fell 15 behind a 10-row ring: skips to the oldest kept
    assert (s.start, s.end, s.skipped) == (15, 25, 15)
    assert s.stamps_ns.tolist() == list(range(1015, 1025))
    assert s.rows[:, 0].tolist() == list(range(15, 25))
    s2 = r.read(20, 3)
    assert (s2.start, s2.end, s2.skipped) == (20, 23, 0) and s2.rows[:, 1].tolist() == [-20, -21, -22]
    assert r.read(25, 10).end == 25  # nothing new
    with pytest.raises(ValueError, match="capacity"):
        Ring(0, 3)


def test_envelope_bins_depth_and_tilt():
    env = Envelope()
    for depth, tilt in [(140.2, 3.4), (140.9, 3.9), (131.0, -12.2), (np.nan, 1.0)]:
        env.add(depth, tilt)
    snap = env.snapshot()
    assert sorted(snap["cells"]) == [[25, 12, 1], [30, 3, 2]]
    assert (snap["depth_min_mm"], snap["depth_max_mm"], snap["tilt_max_deg"]) == (131.0, 140.9, 12.2)


class _FakeFeed:
    """What serve_client reads: three rings and the status inputs."""

    def __init__(self, capacity: int):
        self.state = Ring(capacity, len(STATE_COLUMNS))
        self.reference = Ring(capacity, 4)
        self.vision = Ring(capacity, 5)
        self.current_cache = None
        self.latest: dict = {}
        self.latest_receive_ns: dict = {}
        self.ws_clients = 0
        self.ws_dropped = 0
        self.batch_cache = BatchCache()


class _SlowSocket:
    """A websocket whose sends block until released, recording every message."""

    def __init__(self):
        self.sent: list[dict] = []
        self.release = asyncio.Event()
        self.first_batch = asyncio.Event()
        self.closed = asyncio.Event()
        self.all_seen = asyncio.Event()
        self.accounted = 0  # state rows received or reported skipped

    async def send_text(self, text: str) -> None:
        msg = json.loads(text)
        self.sent.append(msg)
        self.accounted += len(msg.get("state", [])) + msg.get("skipped", 0)
        if self.accounted >= 1000:
            self.all_seen.set()
        if msg["type"] == "batch":
            self.first_batch.set()
            await self.release.wait()  # the client is not reading

    async def receive(self) -> dict:
        await self.closed.wait()
        return {"type": "websocket.disconnect"}


def test_slow_client_gets_bounded_batches_then_the_newest(monkeypatch):
    import services.dashboard.websocket as wsmod

    monkeypatch.setattr(wsmod.payload, "state_now", lambda feed, t0: {"newest": feed.state.total})
    monkeypatch.setattr(wsmod.payload, "status", lambda feed, t0: {})
    cfg = DashboardConfig(max_batch_rows=100, trail_samples=300, push_status_period_s=10.0)
    feed = _FakeFeed(capacity=300)

    async def scenario() -> _SlowSocket:
        sock = _SlowSocket()
        wake = Wake(asyncio.get_running_loop())
        task = asyncio.create_task(serve_client(sock, feed, wake, cfg, 0, "viewer"))
        await sock.first_batch.wait()  # the status batch: the client now blocks the sender

        # 1000 states arrive from a bus thread while the client reads nothing.
        def produce() -> None:
            for k in range(1000):
                feed.state.append(k, np.full(len(STATE_COLUMNS), float(k)))
                wake.from_thread()

        t = threading.Thread(target=produce)
        t.start()
        await asyncio.to_thread(t.join)
        sock.release.set()
        await asyncio.wait_for(sock.all_seen.wait(), 10)
        sock.closed.set()
        await asyncio.wait_for(task, 5)
        return sock

    sock = asyncio.run(scenario())
    batches = [m for m in sock.sent if m["type"] == "batch"]
    assert all(len(b["state"]) <= 100 for b in batches)  # bounded messages
    got = [int(r[1]) for b in batches for r in b["state"]]
    skipped = sum(b["skipped"] for b in batches)
    # The ring held the newest 300: the client skipped the 700 it could no longer get, then
    # received the rest in order with nothing repeated, ending on the newest state.
    assert skipped == 700 and got == list(range(700, 1000))
    assert batches[-1]["current"] == {"newest": 1000}
