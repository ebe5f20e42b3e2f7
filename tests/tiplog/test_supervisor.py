"""The supervisor of `tiplog up`: back-off on quick deaths, reset after a stable run, services
waiting for what they need, every change reported; real child processes, a stepped clock."""

from __future__ import annotations

import subprocess
import sys
import time

from tiplog.supervisor import Child, Supervisor
from tiplog.v1 import system_pb2

R = system_pb2.ServiceRunState


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def exiting(code: int):
    return lambda: subprocess.Popen([sys.executable, "-c", f"raise SystemExit({code})"])


def sleeping():
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])


def test_quick_deaths_back_off_doubling_and_are_reported():
    clock, published = Clock(), []
    c = Child("fusion", exiting(3))
    sup = Supervisor([c], publish=published.append, clock=clock, first_delay_s=0.5, max_delay_s=2.0)
    delays = []
    for _ in range(4):
        sup.poll()  # starts (or restarts) it
        assert c.state == R.SERVICE_RUN_STATE_RUNNING
        c.proc.wait(30)
        clock.t += 0.1
        sup.poll()  # notices the exit
        assert c.state == R.SERVICE_RUN_STATE_RESTARTING and c.last_exit_code == 3
        delays.append(c.restart_at - clock.t)
        clock.t = c.restart_at - 0.01
        sup.poll()
        assert c.state == R.SERVICE_RUN_STATE_RESTARTING  # not before its time
        clock.t += 0.01
    assert delays == [0.5, 1.0, 2.0, 2.0]
    events = [s.event for s in published if s.event]
    assert "fusion exited with 3 after 0.1 s; restarting in 1.0 s" in events
    assert events.count("fusion started") == 1
    assert any(e.startswith("fusion restarted (restart 3)") for e in events)
    last = published[-1].services[0]
    assert last.service == "fusion" and last.restarts == 3


def test_a_stable_run_resets_the_back_off():
    clock = Clock()
    c = Child("vision", exiting(1))
    sup = Supervisor([c], clock=clock, stable_after_s=60.0)
    for _ in range(3):  # three quick deaths: 0.5, 1, 2 s
        sup.poll()
        c.proc.wait(30)
        clock.t += 0.1
        sup.poll()
        clock.t = c.restart_at
    sup.poll()
    c.proc.wait(30)
    clock.t += 61.0  # this run lasted a minute
    sup.poll()
    assert c.restart_at - clock.t == 0.5


def test_a_service_waits_for_what_it_needs_and_stop_ends_it():
    clock, ready = Clock(), [False]
    c = Child("fusion", sleeping, ready=lambda: ready[0])
    sup = Supervisor([c], clock=clock)
    sup.poll()
    assert c.state == R.SERVICE_RUN_STATE_WAITING and c.proc is None
    ready[0] = True
    sup.poll()
    proc = c.proc
    assert c.state == R.SERVICE_RUN_STATE_RUNNING and proc.poll() is None
    assert sup.status().services[0].pid == proc.pid
    sup.stop(grace_s=10)
    assert proc.poll() is not None and c.state == R.SERVICE_RUN_STATE_STOPPED


def test_a_killed_service_is_named_by_its_signal():
    clock, published = Clock(), []
    c = Child("recorder", sleeping)
    sup = Supervisor([c], publish=published.append, clock=clock)
    sup.poll()
    c.proc.kill()
    c.proc.wait(30)
    sup.poll()
    assert c.last_exit_code == -9
    assert any("recorder killed by SIGKILL" in s.event for s in published)


def on_sigterm_note(name: str, log: str, delay_s: float):
    """A child that, on SIGTERM, waits `delay_s` and then appends its name to `log`."""
    code = (
        "import signal, sys, time\n"
        "def h(*_):\n"
        f"    time.sleep({delay_s})\n"
        f"    open({log!r}, 'a').write({name!r} + '\\n')\n"
        "    sys.exit(0)\n"
        "signal.signal(signal.SIGTERM, h)\n"
        f"open({log!r} + '.{name}', 'w').close()\n"
        "time.sleep(60)\n"
    )
    return lambda: subprocess.Popen([sys.executable, "-c", code])


def test_stop_last_waits_for_the_others_to_exit(tmp_path):
    # fusion takes 0.5 s to stop (publishing what it still holds); the recorder must still be
    # running then. Signalled together, the recorder would have stopped first.
    log = str(tmp_path / "order")
    children = [
        Child("recorder", on_sigterm_note("recorder", log, 0.0), stop_last=True),
        Child("fusion", on_sigterm_note("fusion", log, 0.5)),
    ]
    seen = []  # (event, states, what had exited) at each report

    def publish(st):
        done = (tmp_path / "order").read_text().split() if (tmp_path / "order").exists() else []
        seen.append((st.event, {r.service: r.state for r in st.services}, done))

    sup = Supervisor(children, publish=publish, clock=Clock())
    sup.poll()
    for name in ("recorder", "fusion"):  # both handlers installed before the stop
        for _ in range(300):
            if (tmp_path / f"order.{name}").exists():
                break
            time.sleep(0.05)
    sup.stop(grace_s=10)
    assert (tmp_path / "order").read_text().split() == ["fusion", "recorder"]
    assert all(c.state == R.SERVICE_RUN_STATE_STOPPED for c in children)
    # the recorder, still running, is told that the others have stopped, so its file says so
    between = [s for s in seen if s[0] == "fusion stopped; stopping recorder"]
    assert len(between) == 1
    _, states, done = between[0]
    assert states == {"recorder": R.SERVICE_RUN_STATE_RUNNING, "fusion": R.SERVICE_RUN_STATE_STOPPED}
    assert done == ["fusion"]
    assert seen[-1][0] == "stopped"


def test_events_no_recorder_recorded_are_held_and_handed_over_with_their_stamps():
    clock, published = Clock(), []
    recording = [False]
    rec = Child("recorder", exiting(1), first_delay_s=0.05)
    sup = Supervisor([rec], publish=published.append, clock=clock, recording=lambda: recording[0])
    sup.poll()  # started: nobody records yet
    rec.proc.wait(30)
    clock.t += 0.2
    sup.poll()  # its death: held as well
    assert abs(rec.restart_at - clock.t - 0.05) < 1e-9  # the recorder's own first delay
    held = [s.event for s in sup.held]
    assert held == ["recorder started", "recorder exited with 1 after 0.2 s; restarting in 0.05 s"], held
    stamps = [s.header.stamp_ns for s in sup.held]
    n_live = len(published)
    recording[0] = True
    sup.poll()  # a recorder records again: both published once more, replayed, stamps kept
    again = published[n_live:]
    assert [s.event for s in again if s.replayed] == held
    assert [s.header.stamp_ns for s in again if s.replayed] == stamps
    assert not sup.held and not any(s.replayed for s in published[:n_live])
    clock.t += 1.0
    sup.poll()
    assert not sup.held  # while recording nothing is held
    sup.stop()


def test_a_service_failing_at_start_is_given_up_on_with_its_error_line():
    import io

    def failing() -> subprocess.Popen:
        code = "import sys; print('loading'); print('config error: x.y: bad', file=sys.stderr); sys.exit(2)"
        return subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE)

    clock, published, relayed = Clock(), [], io.BytesIO()
    c = Child("dashboard", failing)
    sup = Supervisor([c], publish=published.append, clock=clock, give_up_after=3, err_out=relayed)
    for _ in range(3):
        sup.poll()  # starts (or restarts) it
        c.proc.wait(30)
        clock.t += 0.1
        sup.poll()  # notices the exit
        clock.t = max(clock.t, c.restart_at)
    assert c.state == R.SERVICE_RUN_STATE_FAILED and sup.failed == [c]
    sup.poll()
    assert c.state == R.SERVICE_RUN_STATE_FAILED and c.proc is None  # not restarted
    events = [s.event for s in published if s.event]
    assert (
        events[-1]
        == "dashboard failed at start 3 times in a row (exited with 2); not restarted: config error: x.y: bad"
    )
    assert "dashboard exited with 2 after 0.1 s; restarting in 0.5 s: config error: x.y: bad" in events
    run = published[-1].services[0]
    assert run.state == R.SERVICE_RUN_STATE_FAILED and run.last_error == "config error: x.y: bad"
    assert relayed.getvalue().decode().splitlines() == ["config error: x.y: bad"] * 3  # passed on as it came
    sup.stop()
    assert c.state == R.SERVICE_RUN_STATE_FAILED


def test_a_service_failing_later_than_its_start_is_not_given_up_on():
    clock = Clock()
    c = Child("vision", exiting(1))
    sup = Supervisor([c], clock=clock, give_up_after=2, start_grace_s=5.0)
    for _ in range(3):
        sup.poll()
        c.proc.wait(30)
        clock.t += 6.0  # ran longer than the start's grace
        sup.poll()
        clock.t = max(clock.t, c.restart_at)
    assert c.state == R.SERVICE_RUN_STATE_RESTARTING and c.failed_starts == 0


SPARE = (
    "import sys, time; line = sys.stdin.readline()\n"
    "if not line.strip(): raise SystemExit(7)\n"  # its supervisor gone: never joins
    "print('called', flush=True); time.sleep(60)"
)


def test_a_dead_service_is_replaced_by_its_spare_and_a_new_spare_follows(tmp_path):
    clock = Clock()
    outs = []

    def spare():
        out = open(tmp_path / f"spare{len(outs)}.out", "w")  # noqa: SIM115 - closed below
        outs.append(out)
        return subprocess.Popen([sys.executable, "-c", SPARE], stdin=subprocess.PIPE, stdout=out)

    c = Child("fusion", sleeping, first_delay_s=0.05, spawn_spare=spare)
    sup = Supervisor([c], clock=clock, spare_after_s=5.0)
    try:
        sup.poll()
        first = c.proc
        assert c.spare is None  # not while the system starts
        clock.t += 5.0
        sup.poll()
        ready = c.spare
        assert ready is not None and ready.poll() is None
        first.kill()
        first.wait(30)
        sup.poll()  # notices the death
        clock.t += 0.05
        sup.poll()  # the restart calls the spare up
        assert c.proc is ready and c.spare is None and c.restarts == 1
        _wait_for(lambda: (tmp_path / "spare0.out").read_text() == "called\n")
        clock.t += 5.0
        sup.poll()
        assert c.spare is not None and c.spare is not ready  # the next spare
        second_spare = c.spare
    finally:
        sup.stop(grace_s=5.0)
        for out in outs:
            out.close()
    assert ready.poll() is not None and second_spare.poll() is not None  # stop ends spares too
    assert (tmp_path / "spare1.out").read_text() == ""  # never called up


def test_a_restart_without_a_live_spare_starts_afresh():
    clock = Clock()
    spares = []

    def spare():
        p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(1)"], stdin=subprocess.PIPE)
        spares.append(p)
        return p

    c = Child("fusion", sleeping, first_delay_s=0.05, spawn_spare=spare)
    sup = Supervisor([c], clock=clock, spare_after_s=0.0)
    try:
        sup.poll()
        sup.poll()  # its spare starts, and dies
        spares[0].wait(30)
        c.proc.kill()
        c.proc.wait(30)
        sup.poll()
        clock.t += 0.05
        sup.poll()
        assert c.proc is not None and c.proc not in spares and c.proc.poll() is None
    finally:
        sup.stop(grace_s=5.0)


def _wait_for(pred, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)
