"""One browser's websocket: the history on connect, then every new row as it arrives.

A bus callback only schedules a wake-up on the event loop (at most one pending at a time).
Each client's sender reads from its own cursors in the rings and sends one message per wake-up
with every row that arrived since (none dropped from the trail while the client keeps up).
While a send waits on a slow client, rows simply accumulate in the ring: the next message
carries them all, up to `max_batch_rows`; a client more than a ring behind skips ahead and is
told how many rows it missed. Nothing queues per client. All clients together are sent at most
`ws_messages_per_s` messages a second: with a few clients each state leaves alone as it
arrives; with many, each client's messages are paced (every sender waking on the same tick, so
their rows are read and encoded once) and carry several rows, so that the event loop, which
also answers the API, is not spent on one socket write per client per state. A client that does not take a message
within `ws_send_timeout_s` (it stopped reading, or reads slower than the push rate) is dropped
and counted (`feed.ws_dropped`): what waits for it in the socket buffers is bounded.

Messages (JSON):
- hello: {type, columns, t0_ns, role, trail_samples}
- batch: {type, sent_ns, state, reference, vision, skipped, current?, status?}
  `sent_ns` is the dashboard's host clock (int64 ns, CLOCK_MONOTONIC) as the message leaves.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from typing import Any

from starlette.websockets import WebSocket, WebSocketDisconnect

from services.dashboard import payload
from services.dashboard.config import DashboardConfig
from services.dashboard.feed import BusFeed
from services.dashboard.ring import Ring
from tiplog.clock import now_ns

log = logging.getLogger("tiplog.dashboard")


class Wake:
    """Wake-ups from bus threads to every sender on one event loop, coalesced."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self.loop = loop
        self.event = asyncio.Event()
        self._pending = False
        self._lock = threading.Lock()

    def from_thread(self) -> None:
        """Called on a bus thread after new rows: schedules one wake-up if none is pending."""
        with self._lock:
            if self._pending:
                return
            self._pending = True
        try:
            self.loop.call_soon_threadsafe(self._fire)
        except RuntimeError:  # loop closed while shutting down
            pass

    def _fire(self) -> None:
        with self._lock:
            self._pending = False
        event, self.event = self.event, asyncio.Event()
        event.set()


def _current(feed: BusFeed, t0_ns: int) -> dict[str, Any]:
    """The newest state as JSON-ready dict, built once per new state for all clients (the
    senders share one event loop thread, so the cache needs no lock)."""
    total = feed.state.total
    hit = feed.current_cache
    if hit is None or hit[0] != total:
        hit = feed.current_cache = (total, payload.state_now(feed, t0_ns))
    return hit[1]


def _predicted(feed: BusFeed) -> list[float] | None:
    """Tip of fusion/predicted (the state carried forward to the present), base frame, mm."""
    p = feed.latest.get("fusion/predicted")
    if p is None:
        return None
    tip = [round(v * 1e3, 4) for v in (p.tip_m.x, p.tip_m.y, p.tip_m.z)]
    return tip if all(v == v and abs(v) < 1e9 for v in tip) else None


def _dumps(msg: Any) -> str:
    return json.dumps(msg, separators=(",", ":"), allow_nan=False)


class BatchCache:
    """JSON text shared by every client's sender (all on one event loop thread, so no lock):
    the rows of a ring slice (rows once written do not change), the newest state, and the
    status (rebuilt at most every `status_reuse_ns`). Clients that keep up send the same text."""

    def __init__(self, status_reuse_ns: int = 50_000_000, max_slices: int = 256):
        self.status_reuse_ns = status_reuse_ns
        self.max_slices = max_slices
        self._rows: dict[tuple[str, int, int], str] = {}
        self._current: tuple[int, str] | None = None
        self._status: tuple[int, str] | None = None

    def rows(self, key: str, ring: Ring, cursor: int, max_rows: int, t0_ns: int) -> tuple[str, int, int]:
        """The rows of `ring` from `cursor` as JSON text, with the new cursor and how many rows
        were skipped. Only the first reader of a span copies and encodes it."""
        start, end, skipped = ring.span(cursor, max_rows)
        k = (key, start, end)
        text = self._rows.get(k)
        if text is None:
            sl = ring.read(start, max_rows, end)
            skipped += sl.skipped  # overwritten between the span and the read: rare
            k = (key, sl.start, sl.end)
            end = sl.end
            if len(self._rows) >= self.max_slices:
                self._rows.clear()
            text = self._rows[k] = _dumps(payload.rows(sl, t0_ns))
        return text, end, skipped

    def current(self, feed: BusFeed, t0_ns: int) -> str:
        total = feed.state.total
        if self._current is None or self._current[0] != total:
            self._current = (total, _dumps(_current(feed, t0_ns)))
        return self._current[1]

    def status(self, feed: BusFeed, t0_ns: int) -> str:
        t = now_ns()
        if self._status is None or t - self._status[0] >= self.status_reuse_ns:
            self._status = (t, _dumps(payload.status(feed, t0_ns)))
        return self._status[1]


async def serve_client(
    websocket: WebSocket, feed: BusFeed, wake: Wake, config: DashboardConfig, t0_ns: int, role: str
) -> None:
    """Send to one accepted websocket until it closes, or until it stops taking messages."""
    feed.ws_clients += 1
    opened_ns = now_ns()
    ended = "closed"
    try:
        hello = {
            "type": "hello",
            "columns": payload.columns(),
            "t0_ns": t0_ns,
            "role": role,
            "trail_samples": config.trail_samples,
        }
        await send_bounded(websocket, _dumps(hello), config.ws_send_timeout_s)
        receiver = asyncio.create_task(_drain_incoming(websocket))
        sender = asyncio.create_task(_send_loop(websocket, feed, wake, config, t0_ns))
        done, pending = await asyncio.wait({receiver, sender}, return_when=asyncio.FIRST_COMPLETED)
        for task in pending:
            task.cancel()
        for task in pending:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for task in done:
            exc = task.exception()
            if isinstance(exc, SlowClient):
                raise exc
            if exc is not None and not isinstance(exc, WebSocketDisconnect | ConnectionError | RuntimeError):
                log.warning("websocket client ended with %r", exc)
            ended = f"closed ({exc!r})" if exc is not None else f"closed by the client ({task.result()})"
    except SlowClient as e:
        feed.ws_dropped += 1
        ended = "dropped"
        log.warning("websocket client %s dropped: %s (%d dropped so far)", _peer(websocket), e, feed.ws_dropped)
    finally:
        feed.ws_clients -= 1
        log.info(
            "websocket client %s %s after %.1f s (%d connected)",
            _peer(websocket), ended, (now_ns() - opened_ns) / 1e9, feed.ws_clients,
        )  # fmt: skip


class SlowClient(Exception):
    """A websocket client that did not take a message in time."""


async def send_bounded(websocket: WebSocket, text: str, timeout_s: float) -> None:
    """Send `text`, or raise SlowClient when the client has not taken it within `timeout_s`."""
    try:
        # asyncio.timeout, not wait_for: no task per message (wait_for makes one on 3.11)
        async with asyncio.timeout(timeout_s):
            await websocket.send_text(text)
    except TimeoutError:
        raise SlowClient(f"took no message for {timeout_s:g} s") from None


def _peer(websocket: WebSocket) -> str:
    c = getattr(websocket, "client", None)
    return f"{c.host}:{c.port}" if c else "?"


async def _drain_incoming(websocket: WebSocket) -> str:
    """The page sends nothing that matters; reading notices a close at once (its code, said)."""
    while True:
        msg = await websocket.receive()
        if msg["type"] == "websocket.disconnect":
            return f"code {msg.get('code')}"


async def _send_loop(websocket: WebSocket, feed: BusFeed, wake: Wake, config: DashboardConfig, t0_ns: int) -> None:
    cursors = {"state": 0, "reference": 0, "vision": 0}
    rings = {"state": feed.state, "reference": feed.reference, "vision": feed.vision}
    period_ns = int(config.push_status_period_s * 1e9)
    next_status = 0
    predicted_sent_ns = 0
    while True:
        event = wake.event  # taken before looking, so a row arriving now still wakes us
        behind = any(cursors[k] < r.total for k, r in rings.items())
        if not behind and now_ns() < next_status:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(0.0, (next_status - now_ns()) / 1e9)):
                    await event.wait()
        cache: BatchCache = feed.batch_cache
        parts = ['{"type":"batch"']
        skipped = 0
        new_rows = {}
        for key, ring in rings.items():
            text, end, n_skipped = cache.rows(key, ring, cursors[key], config.max_batch_rows, t0_ns)
            new_rows[key] = end > cursors[key] + n_skipped
            cursors[key] = end
            skipped += n_skipped
            parts.append(f',"{key}":{text}')
        parts.append(f',"skipped":{skipped}')
        status_due = now_ns() >= next_status
        if not (new_rows["state"] or status_due or new_rows["reference"] or new_rows["vision"]):
            continue
        if new_rows["state"]:
            parts.append(f',"current":{cache.current(feed, t0_ns)}')
            predicted_ns = feed.latest_receive_ns.get("fusion/predicted", 0)
            if predicted_ns != predicted_sent_ns:
                predicted_sent_ns = predicted_ns
                parts.append(f',"predicted":{_dumps(_predicted(feed))}')
        if status_due:
            parts.append(f',"status":{cache.status(feed, t0_ns)}')
            next_status = now_ns() + period_ns
        parts.append(f',"sent_ns":{now_ns()}}}')
        await send_bounded(websocket, "".join(parts), config.ws_send_timeout_s)
        await asyncio.sleep(pace_s(feed.ws_clients, config.ws_messages_per_s, time.monotonic()))


def pace_s(clients: int, messages_per_s: float, now_s: float) -> float:
    """How long a sender waits after a message: until the next tick of period clients /
    `messages_per_s` on the monotonic clock (the event loop's), so that every client sends at
    most that often and, all waking on the same tick, reads the same rows (encoded once)."""
    period_s = max(clients, 1) / messages_per_s
    return period_s - now_s % period_s
