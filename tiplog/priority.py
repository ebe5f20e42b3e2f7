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


# The kernel's unbound workers (`kworker/u<pool>:<n>`) run the tty layer's flip-buffer work: a
# serial device's bytes (USB CDC-ACM as much as the bench's pseudo-terminal) reach read() only
# after one of them has run flush_to_ldisc. They run at nice 0 beside every other task, so on a
# loaded two-core host they wait for a core, and the device's samples reach the gateway hundreds
# of milliseconds late, whatever priority the gateway itself has. The pool creates and retires
# workers as it needs them, so the priority is applied again every status period.
KERNEL_WORKER_PREFIX = "kworker/u"


def kernel_workers(proc: str = "/proc") -> list[tuple[int, str, int]]:
    """(pid, name, nice) of the kernel's unbound workers: kernel threads (children of kthreadd,
    pid 2) whose name starts with KERNEL_WORKER_PREFIX. Empty where /proc shows none (a
    container without the host's process namespace)."""
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
            out.append((int(pid), name, int(stat.rsplit(")", 1)[1].split()[16])))
    return out


class KernelWorkerPriority:
    """Keeps the kernel's unbound workers at nice `nice` (< 0; needs root or CAP_SYS_NICE, and the
    host's process namespace in a container). `apply()` raises the workers above it, `restore()`
    puts them back; what it cannot do is logged once, never raised."""

    def __init__(self, nice: int, log: logging.Logger, proc: str = "/proc", setpriority=os.setpriority):
        if not -20 <= nice < 0:
            raise ValueError(f"kernel worker nice must be within [-20, 0) (got {nice})")
        self.nice = nice
        self.raised = 0  # workers raised so far (new ones keep coming)
        self.refused = ""  # why the last raise failed ("" while none did)
        self._log = log
        self._proc = proc
        self._set = setpriority
        self._said: set[str] = set()
        self._before: dict[int, int] = {}  # pid -> the nice it had, for restore()

    def apply(self) -> int:
        """Raise every worker above `nice` to it; returns how many were raised now."""
        workers = kernel_workers(self._proc)
        if not workers:
            self._once("none", "no kernel workers visible in %s: their priority is left as it is", self._proc)
            return 0
        alive = {pid for pid, _, _ in workers}
        self._before = {pid: v for pid, v in self._before.items() if pid in alive}  # retired ones go
        n = 0
        for pid, name, nice in workers:
            if nice <= self.nice:
                continue
            try:
                self._set(os.PRIO_PROCESS, pid, self.nice)
            except ProcessLookupError:  # retired meanwhile
                continue
            except OSError as e:
                self.refused = f"{name}: {e.strerror or e}"
                self._once(
                    "refused",
                    "kernel workers not raised to nice %d (%s): under load a serial device's bytes can "
                    "wait for a core; run as root or with CAP_SYS_NICE",
                    self.nice,
                    self.refused,
                )
                return n
            self._before.setdefault(pid, nice)
            n += 1
        if n and not self.raised:
            self._log.info("kernel workers (%s*) raised to nice %d: %d", KERNEL_WORKER_PREFIX, self.nice, n)
        self.raised += n
        return n

    def restore(self) -> int:
        """Put the workers raised (and still workers: a retired one's pid may be another process's
        now) back to the nice they had; returns how many."""
        alive = {pid for pid, _, _ in kernel_workers(self._proc)}
        n = 0
        for pid, nice in self._before.items():
            if pid not in alive:
                continue
            try:
                self._set(os.PRIO_PROCESS, pid, nice)
                n += 1
            except OSError:  # retired, or no longer ours to change
                continue
        self._before.clear()
        return n

    def _once(self, key: str, msg: str, *args) -> None:
        if key not in self._said:
            self._said.add(key)
            self._log.warning(msg, *args)
