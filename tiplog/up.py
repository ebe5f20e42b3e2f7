"""`tiplog up`: the whole system on one machine, as compose runs it on the cart.

This process holds the Zenoh session in router mode that every service connects to (no
router binary needed), starts each service as its own process, restarts one that dies, and
stops them all on Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time

from tiplog.bus import Bus, BusConfig

log = logging.getLogger("tiplog.up")

DEFAULT_SERVICES = ["bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard"]


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="endpoint of the router this process holds")
    p.add_argument("--services", default=",".join(DEFAULT_SERVICES), help="comma list of services to start")
    p.add_argument("-c", "--config", help="YAML configuration passed to every service")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until interrupted)")
    p.set_defaults(func=run)


def _spawn(name: str, endpoint: str, config: str | None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", f"services.{name}", "--connect", endpoint]
    if config:
        cmd += ["--config", config]
    return subprocess.Popen(cmd, env=os.environ.copy())


def run(args: argparse.Namespace) -> int:
    names = [s.strip() for s in args.services.split(",") if s.strip()]
    unknown = sorted(set(names) - set(DEFAULT_SERVICES))
    if unknown:
        print(
            f"tiplog up: unknown service(s) {', '.join(unknown)}; known: {', '.join(DEFAULT_SERVICES)}", file=sys.stderr
        )
        return 2
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: threading.Thread(target=stop.set, daemon=True).start())
    router = BusConfig(mode="router", listen=[args.listen], connect=[])
    with Bus(router, service="up") as bus:
        procs = {n: _spawn(n, args.listen, args.config) for n in names}
        log.info("started %s; router on %s", ", ".join(names), args.listen)
        deadline = time.monotonic() + args.duration if args.duration else None
        restarts = dict.fromkeys(names, 0)
        while not stop.wait(0.5):
            if deadline and time.monotonic() > deadline:
                break
            for n, p in procs.items():
                rc = p.poll()
                if rc is not None:
                    restarts[n] += 1
                    delay = min(30.0, 0.5 * 2 ** min(restarts[n], 6))
                    log.warning("%s exited with %s; restarting in %.1f s", n, rc, delay)
                    if stop.wait(delay):
                        break
                    procs[n] = _spawn(n, args.listen, args.config)
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
    return 0
