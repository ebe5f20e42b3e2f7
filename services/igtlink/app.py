"""`python -m services.igtlink`: the fused tip, shaft and trocar live over OpenIGTLink.

Subscribes `fusion/state` (or `fusion/predicted`), serves OpenIGTLink on TCP (`host`:`port`,
loopback 18944 by default) and sends each connected client, at `rate_hz`, states as they
arrive, as TRANSFORM messages in millimetres in the reference (robot base) frame, with header
version 2 metadata (see `services.igtlink.messages`). A state is sent once, never again. With no state for `stale_after_s` fusion is not tracking: INVALID
transforms and a `TiplogStatus` STRING go out every `status_period_s` (and to each client as it
connects) until states come again. The trocar (the registered RCM) needs `calibration_file`;
without one `TrocarToReference` is not sent.
"""

from __future__ import annotations

import errno
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np
from pydantic import Field, field_validator, model_validator

from services.igtlink import messages
from services.igtlink.server import BroadcastServer
from tiplog.bus import Bus, SampleInfo
from tiplog.calibration import Calibration, CalibrationError
from tiplog.clock import now_ns, wall_ns
from tiplog.config import ServiceConfig, host_is_loopback
from tiplog.service import ServiceContext, run_service
from tiplog.v1.fusion_pb2 import FusionState

NAME = "igtlink"
log = logging.getLogger("tiplog.igtlink")
ESTIMATE_TOPICS = ("fusion/state", "fusion/predicted")
TIMER_S = 0.02  # the sender also wakes this often without a state: staleness, status


class IgtlinkConfig(ServiceConfig):
    """Configuration of the OpenIGTLink service (section `igtlink:` of the YAML file)."""

    host: str = "127.0.0.1"  # an interface's address to serve Slicer on another machine
    port: int = Field(18944, ge=1, le=65535)  # OpenIGTLink's registered port
    # OpenIGTLink has no authentication: a non-loopback host needs this too.
    allow_remote: bool = False
    rate_hz: float = Field(50.0, gt=0.0, le=200.0)  # up to the gyro rate, fusion/state's rate
    estimate_topic: str = "fusion/state"
    # No state for this long: fusion is not tracking (INVALID transforms, STRING status).
    stale_after_s: float = Field(0.25, gt=0.0, le=10.0)
    # A client that does not take a message within this is dropped (it reconnects).
    send_timeout_s: float = Field(0.2, gt=0.0, le=10.0)
    # A tiplog calibration YAML file: its RCM is sent as TrocarToReference.
    calibration_file: str | None = None

    @field_validator("estimate_topic")
    @classmethod
    def _estimate_known(cls, v: str) -> str:
        if v not in ESTIMATE_TOPICS:
            raise ValueError(f"must be one of {', '.join(ESTIMATE_TOPICS)} (got {v!r})")
        return v

    @field_validator("calibration_file")
    @classmethod
    def _calibration_loads(cls, v: str | None) -> str | None:
        if v:
            try:
                Calibration.load_yaml(v)
            except CalibrationError as e:
                raise ValueError(str(e)) from None
        return v

    @model_validator(mode="after")
    def _remote_allowed(self) -> IgtlinkConfig:
        if not host_is_loopback(self.host) and not self.allow_remote:
            raise ValueError(
                f"host: {self.host} is not loopback and OpenIGTLink has no authentication; "
                "set allow_remote: true to serve it there anyway"
            )
        return self


# A state this much before its due time still goes out: arrival stamps jitter by a fraction of
# a millisecond, and a state skipped for it would leave a gap of a whole state period.
DUE_SLACK_NS = 1_000_000
PENDING_MAX = 1000  # states between two sender wakes (5 s at the gyro rate)


class Streamer:
    """States in from the bus, OpenIGTLink bytes out from one sender thread calling `tick`
    (on each new state and on a short timer). A state goes out as it arrives once it is due:
    due times are `1 / rate_hz` apart in the states' own time, so a client gets `rate_hz`
    transforms a second, evenly spaced, or every state when they come slower."""

    def __init__(
        self,
        server: BroadcastServer,
        rcm_base_m: np.ndarray | None,
        *,
        rate_hz: float,
        stale_after_s: float,
        status_period_s: float,
        clock: Callable[[], int] = now_ns,
        wall: Callable[[], int] = wall_ns,
    ):
        self.server = server
        self.rcm_base_m = rcm_base_m
        self._period_ns = int(1e9 / rate_hz)
        self._due_ns: int | None = None  # state time from which the next state may go out
        self._stale_ns = int(stale_after_s * 1e9)
        self.wake = threading.Event()  # set on every state: the sender's cue
        self._status_ns = int(status_period_s * 1e9)
        self._clock, self._wall = clock, wall
        self._lock = threading.Lock()
        self._latest: tuple[FusionState, int] | None = None  # (state, arrival on the host clock)
        self._pending: deque[FusionState] = deque(maxlen=PENDING_MAX)  # arrived, not yet looked at
        self._sent_stamp: int | None = None
        self._tracking = False
        self._next_status = 0
        self._connections = 0
        self.states_sent = 0
        self.invalid_sent = 0
        self.rejected = 0  # states that are no pose (not finite, not a unit quaternion)

    def on_state(self, msg: FusionState, _info: SampleInfo) -> None:
        if not messages.is_pose(msg):  # never sent as a pose: fusion goes stale, then INVALID
            self.rejected += 1
            return
        with self._lock:
            self._latest = (msg, self._clock())
            self._pending.append(msg)
        self.wake.set()

    def _wall_s(self, stamp_ns: int, now: int) -> float:
        """A host-clock stamp as seconds since 1970 (OpenIGTLink's header time)."""
        return (self._wall() - (now - stamp_ns)) * 1e-9

    def tick(self) -> None:
        now = self._clock()
        with self._lock:
            latest = self._latest
            pending = list(self._pending)
            self._pending.clear()
        new_client = self.server.connections != self._connections
        self._connections = self.server.connections
        if latest is None or now - latest[1] > self._stale_ns:
            reason = "no fusion state yet" if latest is None else "fusion state stale (not tracking)"
            if self._tracking:
                log.warning("not tracking: %s", reason)
            if self._tracking or new_client or now >= self._next_status:
                self._tracking = False
                self._next_status = now + self._status_ns
                last = int(latest[0].header.stamp_ns) if latest else None
                self._send(messages.invalid_messages(reason, self._wall() * 1e-9, last))
                self.invalid_sent += 1
            return
        out = []
        for state in pending:  # in arrival order: every state that is due goes out
            if self._due(int(state.header.stamp_ns)):
                out += messages.state_messages(state, self._wall_s(int(state.header.stamp_ns), now), self.rcm_base_m)
                self.states_sent += 1
        if not out:
            return
        if not self._tracking:
            log.info("tracking")
            out.insert(0, messages.tracking_message(self._wall() * 1e-9))
            self._tracking = True
        self._send(out)

    def _due(self, stamp: int) -> bool:
        """Whether the state stamped `stamp` goes out; if so the next due time moves on."""
        if stamp == self._sent_stamp:
            return False
        backwards = self._sent_stamp is not None and stamp < self._sent_stamp  # a replay restarted
        if self._due_ns is not None and not backwards and stamp < self._due_ns - DUE_SLACK_NS:
            return False
        # the next due time one period on; after a gap or a jump back, from this state
        if self._due_ns is None or backwards or not -DUE_SLACK_NS <= stamp - self._due_ns < self._period_ns:
            self._due_ns = stamp
        self._due_ns += self._period_ns
        self._sent_stamp = stamp
        return True

    def _send(self, msgs: list) -> None:
        self.server.broadcast(b"".join(m.pack() for m in msgs))


def serve(bus: Bus, config: IgtlinkConfig, stop: threading.Event, ready: threading.Event | None = None) -> Streamer:
    """Run until `stop` is set; returns the streamer (finished) for its counts."""
    rcm = None
    if config.calibration_file:
        rcm = np.asarray(Calibration.load_yaml(config.calibration_file).rcm_base_m, float)
    else:
        log.warning("no calibration_file: TrocarToReference is not sent")
    try:
        server = BroadcastServer(config.host, config.port, send_timeout_s=config.send_timeout_s)
    except OSError as e:
        why = (
            "another OpenIGTLink server holds it; set igtlink.port"
            if e.errno == errno.EADDRINUSE
            else "set igtlink.host to an address of this machine"
            if e.errno == errno.EADDRNOTAVAIL
            else "set igtlink.host and igtlink.port"
        )
        log.error("cannot listen on %s:%d (%s): %s", config.host, config.port, e.strerror or e, why)
        raise SystemExit(1) from None
    with server:
        streamer = Streamer(
            server,
            rcm,
            rate_hz=config.rate_hz,
            stale_after_s=config.stale_after_s,
            status_period_s=config.status_period_s,
        )
        bus.subscribe(config.estimate_topic, streamer.on_state)
        log.info(
            "OpenIGTLink on tcp://%s:%d, %s at up to %g Hz", server.host, server.port, config.estimate_topic,
            config.rate_hz,
        )  # fmt: skip
        if ready is not None:
            ready.set()
        next_log = time.monotonic()
        while not stop.is_set():
            streamer.wake.wait(TIMER_S)
            streamer.wake.clear()
            streamer.tick()
            if time.monotonic() >= next_log:
                next_log = time.monotonic() + 30.0
                log.info(
                    "%d client(s), %d states sent, %d invalid, %d rejected", server.client_count,
                    streamer.states_sent, streamer.invalid_sent, streamer.rejected,
                )  # fmt: skip
    return streamer


def _body(ctx: ServiceContext[IgtlinkConfig]) -> None:
    serve(ctx.bus, ctx.config, ctx.stop)


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, IgtlinkConfig, _body, argv, description=__doc__)
