"""`tiplog up`: the whole system on one machine, as compose runs it on the cart.

This process holds the Zenoh session in router mode that every service connects to (no
router binary needed), starts each service as its own process under `tiplog.supervisor`
(restarted with back-off when it dies, every change reported on `system/supervisor`), prints
where to look, and stops them all on Ctrl-C, SIGTERM or after `--duration`.
"""

from __future__ import annotations

import argparse
import functools
import importlib
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
from tiplog.service import SUPERVISED_ENV
from tiplog.supervisor import Child, Supervisor
from tiplog.userio import UserError, input_file

log = logging.getLogger("tiplog.up")

DEFAULT_SERVICES = ["bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard"]


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
CALIBRATION_READERS = ("fusion", "recorder", "dashboard")
STOP_LAST = ("recorder",)  # records what the others publish as they stop


def _config_fields(name: str) -> set[str]:
    """Fields of a service's configuration model (empty when it cannot be imported here)."""
    from tiplog.config import ServiceConfig

    try:
        mod = importlib.import_module(f"services.{name}.app")
    except Exception:  # a service that fails to import says so itself when started
        return set()
    for v in vars(mod).values():
        if isinstance(v, type) and issubclass(v, ServiceConfig) and v is not ServiceConfig:
            return set(v.model_fields)
    return set()


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
        if n in CALIBRATION_READERS and "calibration_file" in _config_fields(n):
            sets[n].append(f"calibration_file={path}")
    return sets, path


def _spawn(name: str, endpoint: str, config: str | None, sets: list[str] = ()) -> subprocess.Popen:
    cmd = [sys.executable, "-m", f"services.{name}", "--connect", endpoint]
    if config:
        cmd += ["--config", config]
    for s in sets:
        cmd += ["--set", s]
    return subprocess.Popen(cmd, env={**os.environ, SUPERVISED_ENV: "1"})


def banner(names: list[str], config: str | None) -> str:
    """The short block a user sees: where to look, where recordings go, how to stop."""
    dash = load_section(config, "dashboard") if config else {}
    rec = load_section(config, "recorder") if config else {}
    lines = ["", "tiplog is starting: " + ", ".join(names)]
    if "dashboard" in names:
        lines.append(f"  dashboard   http://{dash.get('host', '127.0.0.1')}:{dash.get('port', 8000)}")
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
    if args.config:
        load_section(args.config, "up")  # a missing file or a YAML error stops here, named
    run_dir = Path(tempfile.mkdtemp(prefix="tiplog-up-"))
    sets, calibration = calibration_sets(names, args.calibration, run_dir)
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
            Child(n, functools.partial(_spawn, n, args.listen, args.config, sets[n]), stop_last=n in STOP_LAST)
            for n in names
        ]
        for c in children:
            # The services that read the calibration at start wait for the bench to write it.
            if c.name in CALIBRATION_READERS and calibration is not None:
                c.ready = calibration.exists
        sup = Supervisor(children, publish=status_pub.put, router_endpoint=args.listen)
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
    return 0
