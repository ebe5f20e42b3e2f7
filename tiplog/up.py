"""`tiplog up`: the whole system on one machine, as compose runs it on the cart.

This process holds the Zenoh session in router mode that every service connects to (no
router binary needed), starts each service as its own process, restarts one that dies, and
stops them all on Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
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
from tiplog.config import load_section
from tiplog.userio import UserError, input_file

log = logging.getLogger("tiplog.up")

DEFAULT_SERVICES = ["bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard"]


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="endpoint of the router this process holds")
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
CALIBRATION_READERS = ("fusion", "recorder")


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
    return subprocess.Popen(cmd, env=os.environ.copy())


def run(args: argparse.Namespace) -> int:
    names = [s.strip() for s in args.services.split(",") if s.strip()]
    unknown = sorted(set(names) - set(DEFAULT_SERVICES))
    if unknown:
        print(
            f"tiplog up: unknown service(s) {', '.join(unknown)}; known: {', '.join(DEFAULT_SERVICES)}", file=sys.stderr
        )
        return 2
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
        # Fusion needs the calibration at start: with the bench's file it waits for the bench.
        waiting = {"fusion"} & set(names) if calibration is not None and not calibration.exists() else set()
        procs = {n: _spawn(n, args.listen, args.config, sets[n]) for n in names if n not in waiting}
        if calibration is not None:
            log.info("calibration file: %s", calibration)
        log.info("started %s; router on %s", ", ".join(names), args.listen)
        deadline = time.monotonic() + args.duration if args.duration else None
        restarts = dict.fromkeys(names, 0)
        while not stop.wait(0.5):
            if deadline and time.monotonic() > deadline:
                break
            if waiting and calibration is not None and calibration.exists():
                procs.update({n: _spawn(n, args.listen, args.config, sets[n]) for n in waiting})
                waiting = set()
            for n, p in procs.items():
                rc = p.poll()
                if rc is not None:
                    restarts[n] += 1
                    delay = min(30.0, 0.5 * 2 ** min(restarts[n], 6))
                    log.warning("%s exited with %s; restarting in %.1f s", n, rc, delay)
                    if stop.wait(delay):
                        break
                    procs[n] = _spawn(n, args.listen, args.config, sets[n])
        log.info("stopping; alive: %s", ", ".join(sorted(bus.alive(0.3))) or "none")
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        end = time.monotonic() + 5.0
        for p in procs.values():
            try:
                p.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
    shutil.rmtree(run_dir, ignore_errors=True)
    return 0
