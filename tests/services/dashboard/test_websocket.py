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
from services.dashboard.websocket import BatchCache, Wake, pace_s, serve_client


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


def test_readers_at_one_cursor_share_one_encoding(monkeypatch):
    import services.dashboard.websocket as wsmod

    encoded = []
    real_rows = wsmod.payload.rows
    monkeypatch.setattr(wsmod.payload, "rows", lambda sl, t0: encoded.append(sl.start) or real_rows(sl, t0))
    r = Ring(capacity=10, width=len(STATE_COLUMNS))
    for k in range(25):
        r.append(1000 + k, np.full(len(STATE_COLUMNS), float(k)))
    assert r.span(0, 100) == (15, 25, 15) and r.span(20, 3) == (20, 23, 0) and r.span(25, 10) == (25, 25, 0)
    cache = BatchCache()
    first = cache.rows("state", r, 0, 100, 0)
    assert [cache.rows("state", r, 0, 100, 0) for _ in range(49)] == [first] * 49
    assert first[1:] == (25, 15) and encoded == [15]  # 50 readers, one copy and encoding
    assert [row[1] for row in json.loads(first[0])] == list(range(15, 25))
    assert cache.rows("state", r, 20, 3, 0)[1:] == (23, 0) and encoded == [15, 20]


def test_pace_ticks_are_shared_by_every_client():
    # 50 clients at 2000 messages/s: one message per client every 25 ms, on the same ticks.
    assert pace_s(50, 2000.0, 10.010) == pytest.approx(0.015)
    assert pace_s(50, 2000.0, 10.0249) == pytest.approx(0.0001)
    assert pace_s(1, 2000.0, 3.0002) == pytest.approx(0.0003)
    assert pace_s(0, 2000.0, 3.0002) == pytest.approx(0.0003)  # the count read as a client leaves


class _ReadingSocket:
    """A websocket client that takes every message at once."""

    def __init__(self, n_states: int):
        self.sent: list[dict] = []
        self.n_states = n_states
        self.all_seen = asyncio.Event()
        self.closed = asyncio.Event()

    async def send_text(self, text: str) -> None:
        self.sent.append(json.loads(text))
        if sum(len(m.get("state", [])) for m in self.sent) >= self.n_states:
            self.all_seen.set()

    async def receive(self) -> dict:
        await self.closed.wait()
        return {"type": "websocket.disconnect"}


def test_paced_clients_get_every_state_in_fewer_messages(monkeypatch):
    import services.dashboard.websocket as wsmod

    monkeypatch.setattr(wsmod.payload, "state_now", lambda feed, t0: {"newest": feed.state.total})
    monkeypatch.setattr(wsmod.payload, "status", lambda feed, t0: {})
    # 3 clients at 30 messages/s together: each sends at most every 0.1 s.
    cfg = DashboardConfig(ws_messages_per_s=30.0, trail_samples=1000, push_status_period_s=10.0)
    feed = _FakeFeed(capacity=1000)

    async def scenario() -> list[_ReadingSocket]:
        socks = [_ReadingSocket(200) for _ in range(3)]
        wake = Wake(asyncio.get_running_loop())
        tasks = [asyncio.create_task(serve_client(s, feed, wake, cfg, 0, "viewer")) for s in socks]
        for k in range(200):  # a state every 2 ms, while the senders wait on their pace
            feed.state.append(k, np.full(len(STATE_COLUMNS), float(k)))
            wake.from_thread()
            await asyncio.sleep(0.002)
        for s in socks:
            await asyncio.wait_for(s.all_seen.wait(), 10)
            s.closed.set()
        await asyncio.wait_for(asyncio.gather(*tasks), 5)
        return socks

    for sock in asyncio.run(scenario()):
        batches = [m for m in sock.sent if m["type"] == "batch"]
        assert [int(r[1]) for b in batches for r in b["state"]] == list(range(200))  # every state, in order
        assert len([b for b in batches if b["state"]]) < 200  # several per message
        assert batches[-1]["current"] == {"newest": 200}
