"""A module-level lock for the process-pool test: held in the parent, free in a worker that
imported this module afresh, held for ever in one forked from the parent."""

from __future__ import annotations

import threading

LOCK = threading.Lock()


def try_lock(timeout_s: float) -> bool:
    ok = LOCK.acquire(timeout=timeout_s)
    if ok:
        LOCK.release()
    return ok
