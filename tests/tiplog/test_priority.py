"""lower_this_thread: the calling thread's nice value only, never the process's other threads."""

from __future__ import annotations

import logging
import os
import threading

import pytest

from tiplog.priority import KernelWorkerPriority, kernel_workers, lower_this_thread


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


def _fake_proc(tmp_path, threads: dict[int, tuple]):
    """A /proc with kthreadd's children `threads` (pid -> (name, nice[, policy, rt_priority])) as
    the kernel writes them."""
    (tmp_path / "2" / "task" / "2").mkdir(parents=True, exist_ok=True)
    (tmp_path / "2" / "task" / "2" / "children").write_text(" ".join(str(p) for p in threads) + " ")
    for pid, (name, nice, *sched) in threads.items():
        policy, rt = sched or (os.SCHED_OTHER, 0)
        (tmp_path / str(pid)).mkdir(exist_ok=True)
        # fields after the name: state, ppid, ... nice is the 17th, rt_priority the 38th, policy the 39th
        rest = ["S", "2"] + ["0"] * 14 + [str(nice)] + ["7"] * 20 + [str(rt), str(policy)] + ["7"] * 10
        (tmp_path / str(pid) / "stat").write_text(f"{pid} ({name}) " + " ".join(rest) + "\n")
    return str(tmp_path)


def test_kernel_workers_are_the_unbound_kworkers_of_kthreadd(tmp_path):
    proc = _fake_proc(
        tmp_path,
        {
            7: ("kworker/u8:1-events_unbound", 0),
            8: ("kworker/0:1-mm_percpu_wq", 0),  # bound to a CPU: not the tty's
            9: ("ksoftirqd/0", 0),
            10: ("kworker/u9:0", -20),
            11: ("kworker/u8:2-flush-254:0 (x)", 5),  # a name with spaces and parentheses
        },
    )
    assert kernel_workers(proc) == [
        (7, "kworker/u8:1-events_unbound", 0, os.SCHED_OTHER, 0),
        (10, "kworker/u9:0", -20, os.SCHED_OTHER, 0),
        (11, "kworker/u8:2-flush-254:0 (x)", 5, os.SCHED_OTHER, 0),
    ]
    assert kernel_workers(str(tmp_path / "nothing")) == []


def test_only_workers_above_the_target_are_raised_and_a_refusal_is_said_once(tmp_path, caplog):
    proc = _fake_proc(tmp_path, {7: ("kworker/u8:1", 0), 10: ("kworker/u9:0", -20), 11: ("kworker/u8:2", -10)})
    calls = []
    kw = KernelWorkerPriority(-10, logging.getLogger("t"), proc, lambda which, pid, n: calls.append((which, pid, n)))
    assert kw.apply() == 1 and calls == [(os.PRIO_PROCESS, 7, -10)] and kw.raised == 1
    assert kw.restore() == 1 and calls[-1] == (os.PRIO_PROCESS, 7, 0)  # put back as it was
    assert kw.restore() == 0
    kw.apply()
    (tmp_path / "2" / "task" / "2" / "children").write_text("10 11 ")  # worker 7 retired: its pid is not ours
    n = len(calls)
    assert kw.restore() == 0 and len(calls) == n
    (tmp_path / "2" / "task" / "2" / "children").write_text("7 10 11 ")

    def gone(which, pid, n):
        raise ProcessLookupError(3, "No such process")

    assert KernelWorkerPriority(-10, logging.getLogger("t"), proc, gone).apply() == 0  # retired meanwhile

    def refuse(which, pid, n):
        raise PermissionError(13, "Permission denied")

    kw = KernelWorkerPriority(-10, logging.getLogger("t"), proc, refuse)
    with caplog.at_level(logging.WARNING):
        assert kw.apply() == 0 and kw.apply() == 0
    said = [r.getMessage() for r in caplog.records if "not raised" in r.getMessage()]
    assert len(said) == 1 and "kworker/u8:1: Permission denied" in said[0] and "CAP_SYS_NICE" in said[0]
    assert kw.refused == "kworker/u8:1: Permission denied"


def test_no_visible_workers_is_said_once_and_a_positive_target_is_refused(tmp_path, caplog):
    kw = KernelWorkerPriority(-5, logging.getLogger("t"), str(tmp_path))
    with caplog.at_level(logging.WARNING):
        assert kw.apply() == 0 and kw.apply() == 0
    assert sum("no kernel workers visible" in r.getMessage() for r in caplog.records) == 1
    for bad in (0, 3, -21):
        with pytest.raises(ValueError, match="kernel worker nice"):
            KernelWorkerPriority(bad, logging.getLogger("t"))


def test_this_hosts_kernel_workers_are_read():
    workers = kernel_workers()
    if not workers:
        pytest.skip("no kernel workers visible here (a container without the host's process namespace)")
    assert all(w.name.startswith("kworker/u") and -20 <= w.nice <= 19 and w.pid > 2 for w in workers)
    assert all(w.policy in (os.SCHED_OTHER, os.SCHED_BATCH, os.SCHED_FIFO, os.SCHED_RR) for w in workers)


def test_fifo_puts_the_workers_in_the_real_time_class_and_back(tmp_path, caplog):
    proc = _fake_proc(
        tmp_path,
        {
            7: ("kworker/u8:1", 0),
            10: ("kworker/u9:0", -10),  # reniced, but not real-time: raised
            11: ("kworker/u8:2", 0, os.SCHED_FIFO, 5),  # already above the target: left alone
            12: ("kworker/u8:3", 0, os.SCHED_FIFO, 1),  # at it: left alone
        },
    )
    calls = []

    def setscheduler(pid, policy, param):
        calls.append((pid, policy, param.sched_priority))

    kw = KernelWorkerPriority(0, logging.getLogger("t"), proc, fifo=2, setscheduler=setscheduler)
    assert kw.apply() == 3 and calls == [(7, os.SCHED_FIFO, 2), (10, os.SCHED_FIFO, 2), (12, os.SCHED_FIFO, 2)]
    _fake_proc(tmp_path, {7: ("kworker/u8:1", 0, os.SCHED_FIFO, 2), 10: ("kworker/u9:0", -10, os.SCHED_FIFO, 2),
                          11: ("kworker/u8:2", 0, os.SCHED_FIFO, 5), 12: ("kworker/u8:3", 0, os.SCHED_FIFO, 2)})  # fmt: skip
    assert kw.apply() == 0 and kw.raised == 3  # already there: nothing more
    calls.clear()
    assert kw.restore() == 3
    assert calls == [(7, os.SCHED_OTHER, 0), (10, os.SCHED_OTHER, 0), (12, os.SCHED_FIFO, 1)]  # each as it was

    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    kw = KernelWorkerPriority(0, logging.getLogger("t"), proc, fifo=2, setscheduler=refuse)
    _fake_proc(tmp_path, {7: ("kworker/u8:1", 0)})
    with caplog.at_level(logging.WARNING):
        assert kw.apply() == 0 and kw.apply() == 0
    said = [r.getMessage() for r in caplog.records if "not raised" in r.getMessage()]
    assert len(said) == 1 and "SCHED_FIFO 2" in said[0] and "kworker/u8:1: Operation not permitted" in said[0]
    for bad in (-1, 100):
        with pytest.raises(ValueError, match="real-time priority"):
            KernelWorkerPriority(0, logging.getLogger("t"), fifo=bad)
