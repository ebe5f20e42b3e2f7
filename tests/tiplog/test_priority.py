"""lower_this_thread: the calling thread's nice value only, never the process's other threads."""

from __future__ import annotations

import logging
import os
import threading

from tiplog.priority import lower_this_thread


def thread_nices(pid: int) -> list[int]:
    """The nice value of each thread (task) of process `pid` (Linux /proc)."""
    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = open(f"/proc/{pid}/task/{task}/stat").read()
        except FileNotFoundError:  # the thread ended meanwhile
            continue
        out.append(int(stat.rsplit(")", 1)[1].split()[16]))
    return out


def test_only_the_calling_thread_yields():
    base = os.getpriority(os.PRIO_PROCESS, 0)
    got: list[int] = []
    t = threading.Thread(target=lambda: got.append(lower_this_thread(5, logging.getLogger("t"))))
    t.start()
    t.join()
    assert got == [min(19, base + 5)]
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base  # this thread unchanged
    assert lower_this_thread(0, logging.getLogger("t")) == base
