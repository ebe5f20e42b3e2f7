"""`process_pool` workers never inherit this process's locks: a lock held here when the pool
starts (as Zenoh's, Foxglove's or a logging handler's may be, on another thread) is free in
the worker. A worker forked from this process would find it held and wait on it for ever (the
ablation pool did so once in CI, after the bus tests had left runtimes running)."""

from __future__ import annotations

import threading

from tests.helpers import held_lock
from tiplog.procpool import process_pool


def test_a_lock_held_here_is_free_in_the_pools_workers():
    held = threading.Event()
    release = threading.Event()

    def hold() -> None:  # another thread holds it, as a runtime's thread would
        with held_lock.LOCK:
            held.set()
            release.wait(60)

    t = threading.Thread(target=hold, daemon=True)
    t.start()
    assert held.wait(10)
    try:
        assert not held_lock.try_lock(0.01)  # held here
        with process_pool(2) as pool:
            results = [f.result(timeout=120) for f in [pool.submit(held_lock.try_lock, 5.0) for _ in range(4)]]
        assert results == [True] * 4
    finally:
        release.set()
        t.join(10)
