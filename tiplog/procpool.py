"""Process pools that are safe to start from a process that runs other threads."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of `workers` processes forked from a fresh server process (`forkserver`; `spawn`
    where there is none), never from this one. A fork copies every lock as it stands at that
    instant, and the locks that this process's other threads hold then (Zenoh's and Foxglove's
    runtimes, a logging handler, a BLAS pool) stay held in the child for ever: its first use of
    one hangs the worker, and the pool waits on it. Workers import what they run, so jobs must
    be module-level functions with picklable arguments (as any pool needs)."""
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
