"""The supervisor of `tiplog up`: each service as its own process, restarted with back-off when
it dies, and the state of every one reported on the bus (`system/supervisor`).

Back-off: a service that dies waits 0.5 s before its first restart (a child may ask for less:
those whose absence loses data or blinds the display), doubling per quick death up to 30 s; one that ran
for `stable_after_s` starts again from its first delay. Times are host monotonic seconds;
stamps on the bus are `tiplog.clock.now_ns`.

Given up: a service that exits with an error status within `start_grace_s` of its start
`give_up_after` times in a row (a bad file it names, a missing dependency) is not restarted
again: FAILED, with the last error line it wrote, on the terminal and in the status. A child
whose process writes its stderr to a pipe has each line passed on to ours as it comes, and its
last lines kept for that.

Spares: a child with `spawn_spare` has a second process started once it has run
`spare_after_s`, which prepares (imports, compiled kernels) and waits on its stdin without
joining the bus (`tiplog.service.standby`); when the child dies, its restart calls the spare up
(one line on its stdin) instead of starting a process from nothing, and a new spare follows.

Nothing unrecorded: while `recording()` says no recorder records, every status with an event
is also kept (the last `max_held`); once a recorder records again they are published once
more, `replayed` and with their original stamps, so that its file holds them.
"""

from __future__ import annotations

import logging
import re
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from tiplog.clock import now_ns
from tiplog.v1 import system_pb2

log = logging.getLogger("tiplog.up")

R = system_pb2.ServiceRunState


@dataclass
class Child:
    """One supervised service."""

    name: str
    spawn: Callable[[], subprocess.Popen]
    ready: Callable[[], bool] = lambda: True  # may it start now (e.g. its calibration exists)
    stop_last: bool = False  # stopped only once the others have exited (the recorder: what they
    # publish as they stop, such as fusion's last settled second, is still recorded)
    first_delay_s: float | None = None  # its first restart's delay (None: the supervisor's)
    spawn_spare: Callable[[], subprocess.Popen] | None = None  # a standby process (stdin a pipe)
    proc: subprocess.Popen | None = None
    spare: subprocess.Popen | None = None
    spare_lines: deque = field(default_factory=lambda: deque(maxlen=50))
    spare_relay: threading.Thread | None = None
    state: int = R.SERVICE_RUN_STATE_WAITING
    restarts: int = 0
    quick_deaths: int = 0
    started_at: float = 0.0
    restart_at: float = 0.0
    last_exit_code: int = 0
    last_exit_stamp_ns: int = 0
    failed_starts: int = 0  # exits with an error status soon after the start, in a row
    last_error: str = ""  # the last error line of its last exit ("" when none was seen)
    lines: deque = field(default_factory=lambda: deque(maxlen=50))  # its latest stderr lines
    relay: threading.Thread | None = None


_ERROR_LINE = re.compile(r"error|exception|traceback|fatal|critical|denied|not found|no such", re.IGNORECASE)
_LOG_PREFIX = re.compile(r"^\d{4}-\d\d-\d\d [\d:,.]+ (DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: ")
MAX_ERROR_CHARS = 300


def error_line(lines: list[str]) -> str:
    """The line that says why a process stopped: the last that reads as an error, else the last."""
    lines = [ln for ln in lines if ln.strip()]
    if not lines:
        return ""
    chosen = next(
        (ln for ln in reversed(lines) if _ERROR_LINE.search(ln) and not ln.startswith("Traceback")), lines[-1]
    )
    chosen = _LOG_PREFIX.sub("", chosen.strip())  # the message, without the log's time and level
    return chosen if len(chosen) <= MAX_ERROR_CHARS else chosen[: MAX_ERROR_CHARS - 3] + "..."


def _relay(stream, out, lock: threading.Lock, keep: deque) -> None:
    """Pass a child's stderr on to `out` line by line, keeping the latest lines in `keep`."""
    try:
        for raw in iter(stream.readline, b""):
            keep.append(raw.decode(errors="replace").rstrip("\r\n"))
            with lock:
                try:
                    out.write(raw)
                    out.flush()
                except (OSError, ValueError):  # our own stderr is gone: keep reading, or the child blocks
                    pass
    finally:
        stream.close()


@dataclass
class Supervisor:
    """Starts, watches and restarts `children`; `publish(status)` reports every change and
    `tick()` once a second. Call `poll()` often (every 0.1-0.5 s) from one thread."""

    children: list[Child]
    publish: Callable[[system_pb2.SupervisorStatus], None] = lambda _s: None
    router_endpoint: str = ""
    first_delay_s: float = 0.5
    max_delay_s: float = 30.0
    stable_after_s: float = 60.0
    clock: Callable[[], float] = time.monotonic
    recording: Callable[[], bool] = lambda: True  # does a recorder record what is published now
    max_held: int = 1000
    give_up_after: int = 5  # failed starts in a row
    start_grace_s: float = 30.0  # an error exit sooner than this after the start is a failed start
    err_out: object = None  # where children's piped stderr goes (default: our stderr)
    spare_after_s: float = 5.0  # a child's spare starts once it has run this long (not with the others)
    _last_report: float = field(default=-1e9, init=False)
    _err_lock: threading.Lock = field(default_factory=threading.Lock, init=False)
    held: deque = field(default_factory=deque, init=False)  # statuses no recorder has recorded

    def poll(self) -> None:
        """One round: start what may start, notice exits, restart what is due."""
        now = self.clock()
        for c in self.children:
            if c.state == R.SERVICE_RUN_STATE_WAITING and c.ready():
                self._start(c, now, "started")
            elif c.state == R.SERVICE_RUN_STATE_RUNNING and c.proc is not None:
                rc = c.proc.poll()
                if rc is not None:
                    self._exited(c, rc, now)
                elif c.spawn_spare is not None and now - c.started_at >= self.spare_after_s:
                    self._keep_spare(c)
            elif c.state == R.SERVICE_RUN_STATE_RESTARTING and now >= c.restart_at:
                c.restarts += 1
                self._start(c, now, f"restarted (restart {c.restarts})")
        if now - self._last_report >= 1.0:
            self.report("")
        if self.held and self._recording():
            self.hand_over()

    def _recording(self) -> bool:
        try:
            return bool(self.recording())
        except Exception as e:  # the check must never stop the supervision
            log.debug("recording check failed: %s", e)
            return False

    def hand_over(self) -> None:
        """Publish the held statuses again (`replayed`, original stamps) for the recorder now up."""
        n = len(self.held)
        while self.held:
            st = system_pb2.SupervisorStatus()
            st.CopyFrom(self.held.popleft())
            st.replayed = True
            try:
                self.publish(st)
            except Exception as e:
                log.debug("held supervisor status not published: %s", e)
        log.info("handed %d supervisor event(s) to the recorder", n)

    @property
    def failed(self) -> list[Child]:
        """The children given up on."""
        return [c for c in self.children if c.state == R.SERVICE_RUN_STATE_FAILED]

    def _relay_of(self, name: str, proc: subprocess.Popen, keep: deque) -> threading.Thread | None:
        if proc.stderr is None:
            return None
        out = self.err_out if self.err_out is not None else sys.stderr.buffer
        t = threading.Thread(
            target=_relay, args=(proc.stderr, out, self._err_lock, keep), name=f"stderr-{name}", daemon=True
        )
        t.start()
        return t

    def _keep_spare(self, c: Child) -> None:
        """Start `c`'s spare when it has none (or its spare died)."""
        if c.spare is not None and c.spare.poll() is None:
            return
        if c.spare is not None:
            log.warning("%s's spare exited with %s; starting another", c.name, c.spare.returncode)
        assert c.spawn_spare is not None
        c.spare = c.spawn_spare()
        c.spare_lines = deque(maxlen=50)
        c.spare_relay = self._relay_of(f"{c.name}-spare", c.spare, c.spare_lines)

    def _call_spare(self, c: Child) -> subprocess.Popen | None:
        """`c`'s spare, called up (one line on its stdin), or None when it has none alive."""
        spare, c.spare = c.spare, None
        if spare is None or spare.poll() is not None or spare.stdin is None:
            return None
        try:
            spare.stdin.write(b"up\n")
            spare.stdin.close()
        except OSError:  # it died just now
            return None
        c.lines, c.relay = c.spare_lines, c.spare_relay
        c.spare_relay = None
        return spare

    def _start(self, c: Child, now: float, what: str) -> None:
        spare = self._call_spare(c) if c.restarts > 0 else None
        if spare is not None:
            c.proc = spare
            what += ", its spare called up"
        else:
            c.proc = c.spawn()
            c.lines.clear()
            c.relay = self._relay_of(c.name, c.proc, c.lines)
        c.state = R.SERVICE_RUN_STATE_RUNNING
        c.started_at = now
        log.info("%s %s (pid %d)", c.name, what, c.proc.pid)
        self.report(f"{c.name} {what}")

    def _exited(self, c: Child, rc: int, now: float) -> None:
        ran_s = now - c.started_at
        if c.relay is not None:  # its last lines, the error among them, are still in the pipe
            c.relay.join(1.0)
            c.relay = None
        c.last_error = error_line(list(c.lines)) if rc != 0 else ""
        c.quick_deaths = 0 if ran_s >= self.stable_after_s else c.quick_deaths + 1
        # Killed by a signal is not a failure of its own: the OOM killer, a user, a test.
        c.failed_starts = c.failed_starts + 1 if rc > 0 and ran_s < self.start_grace_s else 0
        first = self.first_delay_s if c.first_delay_s is None else c.first_delay_s
        delay = min(self.max_delay_s, first * 2 ** max(0, c.quick_deaths - 1))
        c.last_exit_code = rc
        c.last_exit_stamp_ns = now_ns()
        c.proc = None
        how = (
            f"killed by {signal.Signals(-rc).name}"
            if rc < 0 and -rc in signal.Signals._value2member_map_
            else f"exited with {rc}"
        )
        said = f": {c.last_error}" if c.last_error else ""
        if c.failed_starts >= self.give_up_after:
            c.state = R.SERVICE_RUN_STATE_FAILED
            event = f"{c.name} failed at start {c.failed_starts} times in a row ({how}); not restarted{said}"
            log.error("%s", event)
            self.report(event)
            return
        c.state = R.SERVICE_RUN_STATE_RESTARTING
        c.restart_at = now + delay
        shown = f"{delay:.2f}" if delay < 0.1 else f"{delay:.1f}"  # the recorder's 0.05 s is not "0.1"
        event = f"{c.name} {how} after {ran_s:.1f} s; restarting in {shown} s{said}"
        log.warning("%s", event)
        self.report(event)

    def status(self, event: str = "") -> system_pb2.SupervisorStatus:
        now = self.clock()
        st = system_pb2.SupervisorStatus(router_endpoint=self.router_endpoint, event=event)
        st.header.stamp_ns = now_ns()
        for c in self.children:
            st.services.append(
                system_pb2.ServiceRun(
                    service=c.name,
                    state=c.state,
                    pid=c.proc.pid if c.proc is not None else 0,
                    restarts=c.restarts,
                    last_exit_code=c.last_exit_code,
                    last_exit_stamp_ns=c.last_exit_stamp_ns,
                    restart_in_s=max(0.0, c.restart_at - now) if c.state == R.SERVICE_RUN_STATE_RESTARTING else 0.0,
                    uptime_s=now - c.started_at if c.state == R.SERVICE_RUN_STATE_RUNNING else 0.0,
                    last_error=c.last_error,
                )
            )
        return st

    def report(self, event: str) -> None:
        self._last_report = self.clock()
        st = self.status(event)
        if event and not self._recording():
            self.held.append(st)
            while len(self.held) > self.max_held:
                self.held.popleft()
        try:
            self.publish(st)
        except Exception as e:  # the report must never stop the supervision
            log.debug("supervisor status not published: %s", e)

    def stop(self, grace_s: float = 5.0) -> None:
        """SIGTERM every running service, SIGKILL what is left after `grace_s`: first those
        not marked `stop_last`, then, once they have exited, the rest."""
        self._stop_spares(grace_s)
        first = [c for c in self.children if not c.stop_last]
        last = [c for c in self.children if c.stop_last]
        self._stop_group(first, grace_s)
        self._mark_stopped(first)
        if last and first:  # while the last (the recorder) still runs, so that it records the stop
            self.report(f"{', '.join(c.name for c in first)} stopped; stopping {', '.join(c.name for c in last)}")
        self._stop_group(last, grace_s)
        self._mark_stopped(last)
        self.report("stopped")

    def _stop_spares(self, grace_s: float) -> None:
        spares = [c.spare for c in self.children if c.spare is not None and c.spare.poll() is None]
        for c in self.children:
            c.spare = None
        for p in spares:
            p.send_signal(signal.SIGTERM)
        for p in spares:
            try:
                p.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()

    @staticmethod
    def _mark_stopped(children: list[Child]) -> None:
        for c in children:
            if c.state != R.SERVICE_RUN_STATE_FAILED:  # given up on stays said
                c.state = R.SERVICE_RUN_STATE_STOPPED
            c.proc = None
            if c.relay is not None:
                c.relay.join(1.0)
                c.relay = None

    @staticmethod
    def _stop_group(children: list[Child], grace_s: float) -> None:
        running = [c for c in children if c.proc is not None and c.proc.poll() is None]
        for c in running:
            c.proc.send_signal(signal.SIGTERM)
        end = time.monotonic() + grace_s
        for c in running:
            try:
                c.proc.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop within %.0f s: killed", c.name, grace_s)
                c.proc.kill()
                c.proc.wait()
