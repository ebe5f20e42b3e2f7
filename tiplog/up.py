"""`tiplog up`: the whole system on one machine, as compose runs it on the cart.

This process holds the Zenoh session in router mode that every service connects to (no
router binary needed), starts each service as its own process under `tiplog.supervisor`
(restarted with back-off when it dies, given up on when it keeps failing at start, every change
reported on `system/supervisor`), prints where to look, and stops them all on Ctrl-C, SIGTERM or
after `--duration`; it exits 1 then when it gave up on a service.
"""

from __future__ import annotations

import argparse
import functools
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from tiplog.bus import Bus, BusConfig
from tiplog.calibration import Calibration, CalibrationError
from tiplog.cliargs import endpoint
from tiplog.config import load_section
from tiplog.holders import device_reader, pty_emulator, tcp_listener
from tiplog.service import STANDBY_ENV, SUPERVISED_ENV, SUPERVISOR_PID_ENV
from tiplog.supervisor import Child, Supervisor
from tiplog.up_config import SERVICES, check_system_config, config_model
from tiplog.userio import UserError, input_file
from tiplog.v1 import recorder_pb2, system_pb2

log = logging.getLogger("tiplog.up")
R = system_pb2.ServiceRunState

DEFAULT_SERVICES = list(SERVICES)


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen",
        default="tcp/127.0.0.1:7447",
        type=endpoint(listening=True),
        help="endpoint of the router this process holds",
    )
    p.add_argument("--services", default=",".join(DEFAULT_SERVICES), help="comma list of services to start")
    p.add_argument("-c", "--config", help="YAML configuration passed to every service")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until interrupted)")
    p.add_argument(
        "--calibration",
        metavar="FILE",
        help="calibration file (tiplog calibrate) for fusion and the recorder; "
        "default with the bench: the bench's as-calibrated constants, written at start-up",
    )
    p.set_defaults(func=run)


# Services that read the calibration file (`calibration_file` in their configuration).
CALIBRATION_READERS = ("fusion", "recorder", "dashboard", "igtlink")
STOP_LAST = ("recorder",)  # records what the others publish as they stop
# Restarted at once the first time: while the recorder is down nothing is recorded, while the
# bench is down no device stream flows, while fusion is down the display is blind.
FIRST_DELAY_S = {"recorder": 0.05, "bench": 0.05, "fusion": 0.05}
# Kept ready (imports and compiled kernels loaded, off the bus) to take over at once when the
# running one dies: fusion's start-up is over a second of imports and kernel loading.
SPARES = ("fusion",)
# The spare starts once fusion has run this long: not within the start, whose imports and loading
# already share the cores, and on whose end the first estimate waits.
SPARE_AFTER_S = 15.0


def _config_fields(name: str) -> set[str]:
    """Fields of a service's configuration model (empty when it cannot be imported here)."""
    model = config_model(name)
    return set(model.model_fields) if model is not None else set()


def _config_default(name: str, field: str) -> object:
    """A service configuration field's default (None when unknown here)."""
    model = config_model(name)
    return model.model_fields[field].default if model is not None and field in model.model_fields else None


def calibration_sets(
    names: list[str], calibration: str | None, run_dir: Path
) -> tuple[dict[str, list[str]], Path | None]:
    """Per service, the `--set` overrides that hand it the calibration file, and that file:
    the user's, or (with the bench) the one the bench writes at start-up; None without either."""
    sets: dict[str, list[str]] = {n: [] for n in names}
    if calibration:
        path = input_file(calibration, "calibration file").resolve()
        try:
            Calibration.load_yaml(path)
        except CalibrationError as e:
            raise UserError(str(e)) from None
        except UnicodeDecodeError:
            raise UserError(f"{path}: not a calibration file (not text)") from None
    elif "bench" in names:
        path = run_dir / "calibration.yaml"
        sets["bench"].append(f"calibration_file={path}")
    else:
        return sets, None
    for n in names:
        fields = _config_fields(n) if n in CALIBRATION_READERS else set()
        # A reader whose model did not import here (an import that failed in this process only)
        # gets it too: fusion without it refuses to start, and again at each restart.
        if n in CALIBRATION_READERS and (not fields or "calibration_file" in fields):
            sets[n].append(f"calibration_file={path}")
    return sets, path


def _tcp_host_port(ep: str) -> tuple[str, int] | None:
    """(host, port) of a `tcp/HOST:PORT` (or tls/quic) endpoint; None for other kinds."""
    proto, _, rest = ep.partition("/")
    if proto not in ("tcp", "tls", "quic", "udp") or ":" not in rest:
        return None
    host, _, port = rest.rpartition(":")
    try:
        return host.strip("[]"), int(port.split("#")[0])
    except ValueError:
        return None


def held_resources(names: list[str], listen: str, config: str | None) -> list[str]:
    """What another process already holds of what this `tiplog up` would take: the router
    endpoint, the dashboard's and the OpenIGTLink service's ports, the bench's device link, the
    gateway's device; one phrase each, naming the holder."""
    held = []
    hp = _tcp_host_port(listen)
    if hp and (h := tcp_listener(hp[1], hp[0])):
        held.append(f"the router endpoint {listen} is held by {h}")
    for name, what in (("dashboard", "the dashboard port"), ("igtlink", "the OpenIGTLink port")):
        if name in names:
            sec = load_section(config, name)
            host = str(sec.get("host", _config_default(name, "host") or "127.0.0.1"))
            port = int(sec.get("port", _config_default(name, "port") or 0))
            if port and (h := tcp_listener(port, host)):
                held.append(f"{what} {host}:{port} is held by {h}")
    link = None
    if "bench" in names:
        link = str(load_section(config, "bench").get("device_link", _config_default("bench", "device_link") or ""))
        if link and (h := pty_emulator(link) or (device_reader(link) if os.path.islink(link) else None)):
            held.append(f"the device link {link} is held by {h}")
    if "sensor_gateway" in names:
        port = str(load_section(config, "sensor_gateway").get("port", _config_default("sensor_gateway", "port") or ""))
        if port and port != link and "://" not in port and (h := device_reader(port)):
            held.append(f"the device {port} is read by {h}")
    return held


def _spawn(name: str, endpoint: str, config: str | None, sets: list[str] = (), spare: bool = False) -> subprocess.Popen:
    cmd = [sys.executable, "-m", f"services.{name}", "--connect", endpoint]
    if config:
        cmd += ["--config", config]
    for s in sets:
        cmd += ["--set", s]
    # stderr through the supervisor, which passes every line on and keeps the last error line.
    env = {**os.environ, SUPERVISED_ENV: "1", SUPERVISOR_PID_ENV: str(os.getpid())}
    if spare:  # waits for a line on stdin (tiplog.service.standby)
        return subprocess.Popen(cmd, env={**env, STANDBY_ENV: "1"}, stderr=subprocess.PIPE, stdin=subprocess.PIPE)
    return subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE)


class RecorderWatch:
    """Whether a recorder records what is published now: its latest recorder/status says
    RECORDING, is fresh, and (for `tiplog up`'s own recorder) came from the process running now."""

    def __init__(self, fresh_s: float = 3.0):
        self.fresh_s = fresh_s
        self.state = 0
        self.at = -1e9  # host monotonic seconds of the latest status

    def on_status(self, msg: recorder_pb2.RecorderStatus, _info: object) -> None:
        self.state = msg.state
        self.at = time.monotonic()

    def recording(self, child: Child | None) -> bool:
        if self.state != recorder_pb2.RECORDER_STATE_RECORDING or time.monotonic() - self.at > self.fresh_s:
            return False
        return child is None or (child.state == R.SERVICE_RUN_STATE_RUNNING and self.at >= child.started_at)


def banner(names: list[str], config: str | None) -> str:
    """The short block a user sees: where to look, where recordings go, how to stop."""
    dash = load_section(config, "dashboard") if config else {}
    rec = load_section(config, "recorder") if config else {}
    igtl = load_section(config, "igtlink") if config else {}
    lines = ["", "tiplog is starting: " + ", ".join(names)]
    if "dashboard" in names:
        lines.append(f"  dashboard   http://{dash.get('host', '127.0.0.1')}:{dash.get('port', 8000)}")
        if dash.get("foxglove_bridge"):
            where = f"ws://{dash.get('foxglove_host', '127.0.0.1')}:{dash.get('foxglove_port', 8765)}"
            lines.append(f"  foxglove    {where}  (layout: config/foxglove_layout.json)")
    if "igtlink" in names:
        where = f"{igtl.get('host', '127.0.0.1')}:{igtl.get('port', 18944)}"
        lines.append(f"  slicer      OpenIGTLink {where}  (OpenIGTLinkIF: client to that host and port)")
    if "recorder" in names:
        out_dir = str(rec.get("out_dir", "recordings"))
        shown = out_dir if Path(out_dir).is_absolute() else f"./{out_dir.removeprefix('./').rstrip('/')}/"
        lines.append(f"  recordings  {shown}  (autostart: {rec.get('autostart', 'device')}; `tiplog info FILE`)")
    lines.append("  stop        Ctrl-C (the recording in progress is closed and stays valid)")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    names = [s.strip() for s in args.services.split(",") if s.strip()]
    unknown = sorted(set(names) - set(DEFAULT_SERVICES))
    if unknown:
        raise UserError(f"--services: unknown service(s) {', '.join(unknown)}; known: {', '.join(DEFAULT_SERVICES)}")
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be positive (got {args.duration})")
    run_dir = Path(tempfile.mkdtemp(prefix="tiplog-up-"))
    try:
        sets, calibration = calibration_sets(names, args.calibration, run_dir)
        # Every section, before anything starts: a bad value is one line naming section and field.
        check_system_config(args.config, names, sets, pending=calibration if not args.calibration else None)
        held = held_resources(names, args.listen, args.config)
        if held:
            raise UserError(
                "cannot start: " + "; ".join(held) + " (another `tiplog up`, or what is left of one): stop it, or "
                "give other --listen / dashboard.port / bench.device_link"
            )
    except BaseException:
        shutil.rmtree(run_dir, ignore_errors=True)
        raise
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: threading.Thread(target=stop.set, daemon=True).start())
    router = BusConfig(mode="router", listen=[args.listen], connect=[])
    try:
        bus = Bus(router, service="up")
    except zenoh.ZError as e:
        shutil.rmtree(run_dir, ignore_errors=True)
        raise UserError(
            f"--listen {args.listen}: cannot listen there ({str(e).split(': ')[-1]}); another `tiplog up` "
            "or a standalone tiplog process (replay, record) holds it: stop it, or give another --listen"
        ) from None
    with bus:
        status_pub = bus.publisher("system/supervisor")
        children = [
            Child(
                n,
                functools.partial(_spawn, n, args.listen, args.config, sets[n]),
                stop_last=n in STOP_LAST,
                first_delay_s=FIRST_DELAY_S.get(n),
                spawn_spare=functools.partial(_spawn, n, args.listen, args.config, sets[n], True)
                if n in SPARES
                else None,
            )
            for n in names
        ]
        watch = RecorderWatch()
        bus.subscribe("recorder/status", watch.on_status)
        recorder = next((c for c in children if c.name == "recorder"), None)
        for c in children:
            # The services that read the calibration at start wait for the bench to write it.
            if c.name in CALIBRATION_READERS and calibration is not None:
                c.ready = calibration.exists
        sup = Supervisor(
            children,
            publish=status_pub.put,
            router_endpoint=args.listen,
            recording=functools.partial(watch.recording, recorder),
            spare_after_s=SPARE_AFTER_S,
        )
        if calibration is not None:
            log.info("calibration file: %s", calibration)
        log.info("starting %s; router on %s", ", ".join(names), args.listen)
        print(banner(names, args.config), flush=True)
        deadline = time.monotonic() + args.duration if args.duration else None
        sup.poll()
        while not stop.wait(0.2):
            if deadline and time.monotonic() > deadline:
                break
            sup.poll()
        log.info("stopping; alive: %s", ", ".join(sorted(bus.alive(0.3))) or "none")
        sup.stop()
    shutil.rmtree(run_dir, ignore_errors=True)
    for c in sup.failed:
        why = f": {c.last_error}" if c.last_error else ""
        print(f"tiplog up: {c.name} was given up on after {c.failed_starts} failed starts{why}", file=sys.stderr)
    return 1 if sup.failed else 0
