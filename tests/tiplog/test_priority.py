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


def _fake_proc(tmp_path, threads: dict[int, tuple[str, int]]):
    """A /proc with kthreadd's children `threads` (pid -> (name, nice)) as the kernel writes them."""
    (tmp_path / "2" / "task" / "2").mkdir(parents=True)
    (tmp_path / "2" / "task" / "2" / "children").write_text(" ".join(str(p) for p in threads) + " ")
    for pid, (name, nice) in threads.items():
        (tmp_path / str(pid)).mkdir()
        # fields after the name: state, ppid, ... nice is the 17th
        rest = ["S", "2"] + ["0"] * 14 + [str(nice)] + ["1"] * 30
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
        (7, "kworker/u8:1-events_unbound", 0),
        (10, "kworker/u9:0", -20),
        (11, "kworker/u8:2-flush-254:0 (x)", 5),
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
    assert all(name.startswith("kworker/u") and -20 <= nice <= 19 and pid > 2 for pid, name, nice in workers)
