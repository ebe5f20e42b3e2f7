"""`python -m services.dashboard`: the live page at http://127.0.0.1:8000 (FastAPI + uvicorn).

Subscribes to fusion/state, bench/robot, vision/*, recorder/status, fusion/diagnostics,
device/status and the liveliness tokens, and pushes them to each browser over a websocket.
Binds to loopback by default; bound to any other address it refuses to start without viewer
and operator tokens (environment or token file, see `services.dashboard.auth`). With
`foxglove_bridge: true` it also serves the bus's topics to the Foxglove app.
"""

from __future__ import annotations

import logging
import ssl
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import uvicorn

from services.dashboard.auth import Tokens, check_binding, load_tokens
from services.dashboard.config import DashboardConfig
from services.dashboard.feed import BusFeed
from services.dashboard.recorder_api import RecorderClient
from services.dashboard.server import create_app
from tiplog.bus import Bus
from tiplog.calibration import Calibration, CalibrationError
from tiplog.service import ServiceContext, run_service
from tiplog.userio import UserError, input_file

NAME = "dashboard"
log = logging.getLogger("tiplog.dashboard")

__all__ = ["NAME", "DashboardConfig", "Running", "main", "start"]


@dataclass
class Running:
    """A dashboard serving in this process: its feed, web server and thread."""

    feed: BusFeed
    server: uvicorn.Server
    thread: threading.Thread
    url: str
    bridge: object | None = None

    def stop(self, timeout_s: float = 10.0) -> None:
        self.server.should_exit = True
        self.thread.join(timeout_s)
        if self.bridge is not None:
            self.bridge.stop()  # type: ignore[attr-defined]
        self.feed.close()


def start(bus: Bus, config: DashboardConfig, tokens: Tokens | None = None) -> Running:
    """Check the binding and tokens, subscribe, and serve on a thread; returns once listening.
    Raises UserError for a bad token setting or calibration file."""
    tokens = tokens if tokens is not None else load_tokens(config.token_file)
    check_binding(config.is_loopback(), config.host, tokens)
    problem = config.foxglove_binding_problem()
    if problem:
        raise UserError(problem)
    calibration = None
    if config.calibration_file:
        try:
            calibration = Calibration.load_yaml(input_file(config.calibration_file, "calibration file"))
        except CalibrationError as e:
            raise UserError(f"{config.calibration_file}: {e}") from None
    if bool(config.tls_certfile) != bool(config.tls_keyfile):
        raise UserError("dashboard: tls_certfile and tls_keyfile go together")
    tls = {}
    if config.tls_certfile:
        tls = {
            "ssl_certfile": str(input_file(config.tls_certfile, "TLS certificate")),
            "ssl_keyfile": str(input_file(config.tls_keyfile, "TLS key")),
        }
        try:  # uvicorn would fail on its own thread, with a traceback: check here
            ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(tls["ssl_certfile"], tls["ssl_keyfile"])
        except (ssl.SSLError, OSError) as e:
            raise UserError(
                f"dashboard: {config.tls_certfile} / {config.tls_keyfile}: not a usable certificate and key ({e})"
            ) from None
    feed = BusFeed(
        bus,
        trail_samples=config.trail_samples,
        reference_samples=config.reference_samples,
        vision_samples=config.vision_samples,
        stale_after_s=config.stale_after_s,
        calibration=calibration,
    )
    app = create_app(feed, config, tokens, RecorderClient(bus, config.recorder_timeout_s))
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=config.host,
            port=config.port,
            log_level="warning",
            access_log=False,
            lifespan="on",
            ws_per_message_deflate=config.ws_per_message_deflate,
            **tls,
        )
    )
    thread = threading.Thread(target=server.run, name="dashboard-http", daemon=True)
    thread.start()
    while not server.started:
        if not thread.is_alive():
            feed.close()
            raise UserError(f"dashboard: cannot listen on {config.host}:{config.port} (see the log above)")
        thread.join(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    host = f"[{config.host}]" if ":" in config.host else config.host
    running = Running(feed, server, thread, f"{'https' if tls else 'http'}://{host}:{port}")
    if config.foxglove_bridge:
        try:
            from services.dashboard.foxglove_bridge import FoxgloveBridge

            running.bridge = FoxgloveBridge.start(bus, config)
        except ImportError as e:
            running.stop()
            raise UserError(
                f"dashboard: foxglove_bridge needs foxglove-sdk (pip install -e '.[foxglove]'): {e}"
            ) from None
        except Exception as e:  # the port taken, most often
            running.stop()
            raise UserError(
                f"dashboard: the Foxglove bridge cannot start on port {config.foxglove_port}: {e}"
            ) from None
    return running


def _body(ctx: ServiceContext[DashboardConfig]) -> None:
    try:
        running = start(ctx.bus, ctx.config)
    except UserError as e:
        ctx.log.error("%s", e)
        raise SystemExit(2) from None
    ctx.log.info(
        "dashboard at %s (%s)",
        running.url,
        "tokens required" if load_tokens(ctx.config.token_file).enabled else "loopback, no tokens",
    )
    try:
        while not ctx.stop.wait(0.5):
            if not running.thread.is_alive():
                ctx.log.error("web server stopped unexpectedly")
                raise SystemExit(1)
    finally:
        running.stop()


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, DashboardConfig, _body, argv, description=__doc__)
