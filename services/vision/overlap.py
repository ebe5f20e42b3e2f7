"""Frames processed side by side, results in frame order.

The network's convolutions (torch) and most of the labeler's array work (numpy, OpenCV)
release the GIL, so two threads each running `Pipeline.process` on its own frame keep two cores
busy while the caller's thread reads and decodes the next frames. Each frame's result depends
on that frame alone and every torch operation runs on one thread, so the observations are the
same, bit for bit, as one frame after another.

- `ordered_map` (offline, `tiplog vision run`): every frame, results yielded in input order.
- `InOrder` (the live service): each worker takes the newest frame when it is free; a result
  is published only after those of the frames taken before it, so observations leave in
  capture order.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def ordered_map(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int = 2,
    depth: int | None = None,
    passthrough: Callable[[T], bool] | None = None,
) -> Iterator[R | T]:
    """fn(item) for every item on `workers` threads, yielded in the order of `items`; items for
    which `passthrough(item)` is true are yielded unchanged, in their place.

    At most `depth` items (default 2 x workers) are computed at once: the reader runs ahead by
    that much and no further. With workers <= 1 everything runs on the caller's thread. An
    exception raised by fn is raised here, at its item's turn."""
    if workers <= 1:
        for it in items:
            yield it if passthrough is not None and passthrough(it) else fn(it)
        return
    depth = max(workers, depth or 2 * workers)
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="vision") as ex:
        queue: deque[tuple[bool, object]] = deque()  # (is a future, future or item)
        in_flight = 0
        try:
            for it in items:
                if passthrough is not None and passthrough(it):
                    queue.append((False, it))
                else:
                    queue.append((True, ex.submit(fn, it)))
                    in_flight += 1
                # hand out what is finished at the head; wait for the oldest when too many run
                while queue and (not queue[0][0] or queue[0][1].done() or in_flight >= depth):  # type: ignore[union-attr]
                    is_future, x = queue.popleft()
                    if is_future:
                        in_flight -= 1
                        yield x.result()  # type: ignore[union-attr]
                    else:
                        yield x  # type: ignore[misc]
            while queue:
                is_future, x = queue.popleft()
                yield x.result() if is_future else x  # type: ignore[union-attr,misc]
        finally:
            for is_future, x in queue:
                if is_future:
                    x.cancel()  # type: ignore[union-attr]


class InOrder:
    """Tickets handed out when a worker takes a frame; `turn(ticket)` waits until every earlier
    ticket is done, so results are published in the order the frames were taken."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._next_ticket = 0
        self._next_done = 0

    def ticket(self) -> int:
        with self._cv:
            t = self._next_ticket
            self._next_ticket += 1
            return t

    def wait_turn(self, ticket: int, timeout_s: float = 5.0) -> bool:
        """True once every earlier ticket is done; False after `timeout_s` (the caller goes on
        rather than stall behind a worker that hangs)."""
        with self._cv:
            return self._cv.wait_for(lambda: self._next_done >= ticket, timeout_s)

    def done(self, ticket: int) -> None:
        with self._cv:
            self._next_done = max(self._next_done, ticket + 1)
            self._cv.notify_all()
