"""Lower priority for the threads that do heavy work which sheds load by itself (vision's network,
the bench's renderer), so that on a busy machine fusion, the gateway and the dashboard never wait
for a core behind them. Per thread, not per process: a Linux thread is a task with its own nice
value, so a service's loading (on the start-up's critical path) and its light real-time threads
(the bench's device stream) keep the normal priority."""

from __future__ import annotations

import logging
import os
import threading


def lower_this_thread(increment: int, log: logging.Logger) -> int:
    """Raise the calling thread's nice value by `increment` (0: unchanged); returns the value
    it runs at. Lowering one's own priority needs no privilege; a refusal is logged, not raised."""
    now = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    if increment <= 0:
        return now
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), min(19, now + increment))
    except OSError as e:
        log.warning("priority of thread %s not lowered: %s", threading.current_thread().name, e)
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
