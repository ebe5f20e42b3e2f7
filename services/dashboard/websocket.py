"""One browser's websocket: the history on connect, then every new row as it arrives.

A bus callback only schedules a wake-up on the event loop (at most one pending at a time).
Each client's sender reads from its own cursors in the rings and sends one message per wake-up
with every row that arrived since (none dropped from the trail while the client keeps up).
While a send waits on a slow client, rows simply accumulate in the ring: the next message
carries them all, up to `max_batch_rows`; a client more than a ring behind skips ahead and is
told how many rows it missed. Nothing queues per client.

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
from typing import Any

from starlette.websockets import WebSocket, WebSocketDisconnect

from services.dashboard import payload
from services.dashboard.config import DashboardConfig
from services.dashboard.feed import BusFeed
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


def _dumps(msg: dict[str, Any]) -> str:
    return json.dumps(msg, separators=(",", ":"), allow_nan=False)


async def serve_client(
    websocket: WebSocket, feed: BusFeed, wake: Wake, config: DashboardConfig, t0_ns: int, role: str
) -> None:
    """Send to one accepted websocket until it closes."""
    await websocket.send_text(
        _dumps(
            {
                "type": "hello",
                "columns": payload.columns(),
                "t0_ns": t0_ns,
                "role": role,
                "trail_samples": config.trail_samples,
            }
        )
    )
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
        if exc is not None and not isinstance(exc, WebSocketDisconnect | ConnectionError | RuntimeError):
            log.warning("websocket client ended with %r", exc)


async def _drain_incoming(websocket: WebSocket) -> None:
    """The page sends nothing that matters; reading notices a close at once."""
    while True:
        msg = await websocket.receive()
        if msg["type"] == "websocket.disconnect":
            return


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
                await asyncio.wait_for(event.wait(), timeout=max(0.0, (next_status - now_ns()) / 1e9))
        msg: dict[str, Any] = {"type": "batch"}
        skipped = 0
        new_state = False
        for key, ring in rings.items():
            s = ring.read(cursors[key], config.max_batch_rows)
            cursors[key] = s.end
            skipped += s.skipped
            msg[key] = payload.rows(s, t0_ns)
            new_state |= key == "state" and s.end > s.start
        msg["skipped"] = skipped
        status_due = now_ns() >= next_status
        if not (new_state or status_due or msg["reference"] or msg["vision"]):
            continue
        if new_state:
            msg["current"] = _current(feed, t0_ns)
            predicted_ns = feed.latest_receive_ns.get("fusion/predicted", 0)
            if predicted_ns != predicted_sent_ns:
                predicted_sent_ns = predicted_ns
                msg["predicted"] = _predicted(feed)
        if status_due:
            msg["status"] = payload.status(feed, t0_ns)
            next_status = now_ns() + period_ns
        msg["sent_ns"] = now_ns()
        await websocket.send_text(_dumps(msg))
