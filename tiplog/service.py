"""The shell every service runs in: arguments, configuration, logging, bus, signals.

    def main(argv=None) -> int:
        return run_service("fusion", FusionConfig, body, argv)

`body(ctx)` does the service's work and returns once `ctx.stop` is set (SIGINT or SIGTERM; under
`tiplog up`, SIGTERM only: `SUPERVISED_ENV`).
The bus, its liveliness token and everything declared on it are closed afterwards, so a
service stops within a fraction of a second of the signal even while idle.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from tiplog.bus import Bus
from tiplog.cliargs import endpoint
from tiplog.config import ConfigError, ServiceConfig, dump, load_config

C = TypeVar("C", bound=ServiceConfig)

# Set by `tiplog up` for its services. A terminal's Ctrl-C reaches every process of the group at
# once; supervised, a service leaves SIGINT to the supervisor, which stops them with SIGTERM in
# order (the recorder last, so that it records what the others publish as they stop).
SUPERVISED_ENV = "TIPLOG_SUPERVISED"
# The supervisor's pid, also set by `tiplog up`: a supervised service stops (SIGTERM, files closed)
# when its supervisor dies, by the kernel's parent-death signal and, should that be missed (a
# supervisor that died before the child asked for it), by noticing that it has been re-parented.
SUPERVISOR_PID_ENV = "TIPLOG_SUPERVISOR_PID"
PR_SET_PDEATHSIG = 1
REPARENT_CHECK_S = 0.5
# Set by `tiplog up` on a service's spare: it prepares (imports, compiled code), then waits for
# one line on its stdin before it opens the bus; end of file or a stop signal ends it.
STANDBY_ENV = "TIPLOG_STANDBY"
log = logging.getLogger("tiplog.service")


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The options every program shares (zenoh-python examples' --mode/--connect/--listen)."""
    g = parser.add_argument_group("bus")
    g.add_argument("--mode", choices=["peer", "client", "router"], help="Zenoh session mode")
    g.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        type=endpoint(listening=False),
        help="endpoint to connect to, e.g. tcp/10.0.0.2:7447 (repeatable)",
    )
    g.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        type=endpoint(listening=True),
        help="endpoint to listen on (repeatable)",
    )
    g.add_argument("--prefix", help="key prefix (default tiplog/)")


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-c", "--config", metavar="FILE", help="YAML configuration file")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="override a configuration field, e.g. --set bus.mode=client (repeatable)",
    )
    parser.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    add_bus_arguments(parser)


def overrides_from_args(args: argparse.Namespace) -> list[tuple[str, object] | str]:
    out: list[tuple[str, object] | str] = list(args.set or [])
    for name in ("mode", "connect", "listen", "prefix"):
        v = getattr(args, name, None)
        if isinstance(v, list):  # `--listen ''` means: none
            v = [e for e in v if e]
        if v is not None:
            out.append((f"bus.{name}", v))
    if getattr(args, "log_level", None):
        out.append(("log_level", args.log_level))
    return out


def ask_parent_death_signal(signum: int = signal.SIGTERM) -> bool:
    """Ask the kernel to send `signum` to this process when its parent dies (Linux prctl);
    False where that is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def watch_supervisor(supervisor_pid: int, stop: threading.Event, slog: logging.Logger) -> threading.Thread | None:
    """Stop when the supervisor `supervisor_pid` is no longer this process's parent: the parent-death
    signal, plus a thread that checks for re-parenting (init or a container's subreaper)."""
    ask_parent_death_signal()
    if os.getppid() != supervisor_pid:
        slog.warning("supervisor (pid %d) is gone: stopping", supervisor_pid)
        stop.set()
        return None

    def watch() -> None:
        while not stop.wait(REPARENT_CHECK_S):
            if os.getppid() != supervisor_pid:
                slog.warning("supervisor (pid %d) is gone (parent now pid %d): stopping", supervisor_pid, os.getppid())
                stop.set()
                return

    t = threading.Thread(target=watch, name="supervisor-watch", daemon=True)
    t.start()
    return t


def setup_logging(level: str = "INFO") -> None:
    logging.basicConfig(
        level=getattr(logging, level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
        force=True,
    )


@dataclass
class ServiceContext(Generic[C]):
    name: str
    config: C
    bus: Bus
    stop: threading.Event = field(default_factory=threading.Event)
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("tiplog"))
    args: argparse.Namespace | None = None


def run_service(
    name: str,
    config_model: type[C],
    body: Callable[[ServiceContext[C]], None],
    argv: Sequence[str] | None = None,
    description: str | None = None,
    extra_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
    check: Callable[[C], None] | None = None,
    prepare: Callable[[C], None] | None = None,
) -> int:
    """Parse arguments, load configuration, open the bus and run `body` until a signal.
    `check` raises ConfigError for what the model alone cannot validate (a file the
    configuration names, a combination of fields): one line, exit 2, before the bus opens.
    As a spare (`STANDBY_ENV`), the service runs `prepare` (what takes time and needs no bus:
    imports, loading compiled code), then waits to be called up (`standby`) before the bus opens."""
    parser = argparse.ArgumentParser(prog=f"python -m services.{name}", description=description)
    add_config_arguments(parser)
    if extra_arguments:
        extra_arguments(parser)
    args = parser.parse_args(argv)
    try:
        config = load_config(config_model, name, args.config, overrides_from_args(args))
        if check is not None:
            check(config)
    except ConfigError as e:
        print(str(e), file=sys.stderr)
        return 2
    setup_logging(config.log_level)
    slog = logging.getLogger(f"tiplog.{name}")
    slog.info("configuration: %s", dump(config))

    stop = threading.Event()
    received: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        # The handler runs on the main thread, possibly while it holds the Event's lock inside
        # wait(); setting the Event from another thread cannot deadlock on that lock.
        # Logging here could deadlock on the handler's lock the same way: log it afterwards.
        received.append(signum)
        threading.Thread(target=stop.set, name="stop", daemon=True).start()

    supervised = os.environ.get(SUPERVISED_ENV) == "1"
    handled = (signal.SIGTERM,) if supervised else (signal.SIGINT, signal.SIGTERM)
    old = {s: signal.signal(s, on_signal) for s in handled}
    if supervised:
        old[signal.SIGINT] = signal.signal(signal.SIGINT, signal.SIG_IGN)
        supervisor_pid = os.environ.get(SUPERVISOR_PID_ENV, "")
        if supervisor_pid.isdigit():
            watch_supervisor(int(supervisor_pid), stop, slog)
    try:
        if os.environ.get(STANDBY_ENV) == "1":
            if prepare is not None:
                prepare(config)
            if not standby(stop, slog):
                return 0
        try:
            bus = Bus(config.bus, service=name, stop=stop)
        except ConnectionError as e:
            slog.error("%s", e)
            return 0 if stop.is_set() else 1
        with bus:
            ctx = ServiceContext(name=name, config=config, bus=bus, stop=stop, log=slog, args=args)
            slog.info("up on %s (mode %s)", config.bus.prefix, config.bus.mode)
            body(ctx)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    slog.info("stopped%s", f" on {signal.Signals(received[0]).name}" if received else "")
    return 0


def standby(stop: threading.Event, slog: logging.Logger) -> bool:
    """A spare's wait: True once a line comes on stdin (called up), False on a stop signal or
    end of file (its supervisor gone). Stdin, not a signal: a line written before the spare is
    ready waits in the pipe, where a signal would be lost or kill it."""
    called = threading.Event()
    woke = threading.Event()

    def read() -> None:
        # os.read, not sys.stdin's buffered reader: a spare told to stop exits with this thread
        # still waiting, and a buffered reader's lock held then is a fatal error at interpreter exit.
        try:
            line = os.read(sys.stdin.fileno(), 4096)
        except (OSError, ValueError):
            line = b""
        if line.strip():
            called.set()
        woke.set()

    threading.Thread(target=read, name="standby", daemon=True).start()
    threading.Thread(target=lambda: (stop.wait(), woke.set()), name="standby-stop", daemon=True).start()
    slog.info("ready, standing by")
    woke.wait()
    if called.is_set() and not stop.is_set():
        slog.info("called up")
        return True
    return False


def idle_until_stopped(ctx: ServiceContext) -> None:
    """Body for a service that only needs to be present on the bus."""
    ctx.stop.wait()
