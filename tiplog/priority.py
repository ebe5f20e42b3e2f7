"""Lower priority for the threads that do heavy work which sheds load by itself (vision's network,
the bench's renderer), so that on a busy machine fusion, the gateway and the dashboard never wait
for a core behind them. Per thread, not per process: a Linux thread is a task with its own nice
value, so a service's loading (on the start-up's critical path) and its light real-time threads
(the bench's device stream) keep the normal priority."""

from __future__ import annotations

import logging
import os
import threading
from typing import NamedTuple


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


# The kernel's unbound workers (`kworker/u<pool>:<n>`) run the tty layer's flip-buffer work: a
# serial device's bytes (USB CDC-ACM as much as the bench's pseudo-terminal) reach read() only
# after one of them has run flush_to_ldisc. They run at nice 0 beside every other task, so on a
# loaded two-core host they wait for a core, and the device's samples reach the gateway hundreds
# of milliseconds late, whatever priority the gateway itself has. A nice value below 0 shortens
# the wait; the real-time class (SCHED_FIFO) ends it: such a worker runs as soon as it wakes.
# The pool creates and retires workers as it needs them, so the priority is applied again every
# status period.
KERNEL_WORKER_PREFIX = "kworker/u"


class KernelWorker(NamedTuple):
    pid: int
    name: str
    nice: int
    policy: int  # os.SCHED_OTHER, os.SCHED_FIFO, ...
    rt_priority: int  # 1-99 in a real-time class, else 0


def kernel_workers(proc: str = "/proc") -> list[KernelWorker]:
    """The kernel's unbound workers: kernel threads (children of kthreadd, pid 2) whose name
    starts with KERNEL_WORKER_PREFIX. Empty where /proc shows none (a container without the
    host's process namespace)."""
    try:
        kids = open(f"{proc}/2/task/2/children").read().split()
    except OSError:
        return []
    out = []
    for pid in kids:
        try:
            stat = open(f"{proc}/{pid}/stat").read()
        except OSError:  # the worker was retired meanwhile
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        if name.startswith(KERNEL_WORKER_PREFIX):
            f = stat.rsplit(")", 1)[1].split()  # from field 3 (state) on: nice is 19, rt_priority 40, policy 41
            out.append(KernelWorker(int(pid), name, int(f[16]), int(f[38]), int(f[37])))
    return out


class KernelWorkerPriority:
    """Keeps the kernel's unbound workers at nice `nice` (< 0), or with `fifo` (1-99) in the
    real-time class SCHED_FIFO at that priority (the nice value then does not matter). Either
    needs root or CAP_SYS_NICE, and the host's process namespace in a container. `apply()` raises
    the workers below the target, `restore()` puts them back; what it cannot do is logged once,
    never raised."""

    def __init__(
        self,
        nice: int,
        log: logging.Logger,
        proc: str = "/proc",
        setpriority=os.setpriority,
        fifo: int = 0,
        setscheduler=os.sched_setscheduler,
    ):
        if fifo:
            if not 1 <= fifo <= 99:
                raise ValueError(f"kernel worker real-time priority must be within [1, 99] (got {fifo})")
        elif not -20 <= nice < 0:
            raise ValueError(f"kernel worker nice must be within [-20, 0) (got {nice})")
        self.nice = nice
        self.fifo = fifo
        self.target = f"SCHED_FIFO {fifo}" if fifo else f"nice {nice}"
        self.raised = 0  # workers raised so far (new ones keep coming)
        self.refused = ""  # why the last raise failed ("" while none did)
        self._log = log
        self._proc = proc
        self._set = setpriority
        self._set_scheduler = setscheduler
        self._said: set[str] = set()
        self._before: dict[int, KernelWorker] = {}  # pid -> as it was, for restore()

    def _below(self, w: KernelWorker) -> bool:
        if self.fifo:
            return w.policy not in (os.SCHED_FIFO, os.SCHED_RR) or w.rt_priority < self.fifo
        return w.nice > self.nice

    def _raise(self, pid: int) -> None:
        if self.fifo:
            self._set_scheduler(pid, os.SCHED_FIFO, os.sched_param(self.fifo))
        else:
            self._set(os.PRIO_PROCESS, pid, self.nice)

    def apply(self) -> int:
        """Raise every worker below the target to it; returns how many were raised now."""
        workers = kernel_workers(self._proc)
        if not workers:
            self._once("none", "no kernel workers visible in %s: their priority is left as it is", self._proc)
            return 0
        alive = {w.pid for w in workers}
        self._before = {pid: w for pid, w in self._before.items() if pid in alive}  # retired ones go
        n = 0
        for w in workers:
            if not self._below(w):
                continue
            try:
                self._raise(w.pid)
            except ProcessLookupError:  # retired meanwhile
                continue
            except OSError as e:
                self.refused = f"{w.name}: {e.strerror or e}"
                self._once(
                    "refused",
                    "kernel workers not raised to %s (%s): under load a serial device's bytes can "
                    "wait for a core; run as root or with CAP_SYS_NICE",
                    self.target,
                    self.refused,
                )
                return n
            self._before.setdefault(w.pid, w)
            n += 1
        if n and not self.raised:
            self._log.info("kernel workers (%s*) raised to %s: %d", KERNEL_WORKER_PREFIX, self.target, n)
        self.raised += n
        return n

    def restore(self) -> int:
        """Put the workers raised (and still workers: a retired one's pid may be another process's
        now) back as they were; returns how many."""
        alive = {w.pid for w in kernel_workers(self._proc)}
        n = 0
        for pid, w in self._before.items():
            if pid not in alive:
                continue
            try:
                if self.fifo:
                    self._set_scheduler(pid, w.policy, os.sched_param(w.rt_priority))
                else:
                    self._set(os.PRIO_PROCESS, pid, w.nice)
                n += 1
            except OSError:  # retired, or no longer ours to change
                continue
        self._before.clear()
        return n

    def _once(self, key: str, msg: str, *args) -> None:
        if key not in self._said:
            self._said.add(key)
            self._log.warning(msg, *args)
