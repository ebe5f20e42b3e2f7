"""Configuration of the dashboard (section `dashboard:` of the YAML file).

Tokens are deliberately not fields here: configuration can be given with `--set` on the
command line and is logged at start. They come from the environment
(`TIPLOG_DASHBOARD_VIEWER_TOKEN`, `TIPLOG_DASHBOARD_OPERATOR_TOKEN`) or from `token_file`
(see `services.dashboard.auth`).
"""

from __future__ import annotations

from pydantic import Field, field_validator

from tiplog.config import ServiceConfig, host_is_loopback


class DashboardConfig(ServiceConfig):
    """Where the dashboard listens and what it keeps. Periods in seconds, rates in Hz."""

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)  # 0: any free port (tests)
    # HTTPS: a PEM certificate (chain) and its key; off when empty. Tokens cross the network in
    # every request: a dashboard bound beyond loopback should use TLS here or behind a proxy.
    tls_certfile: str | None = None
    tls_keyfile: str | None = None
    # YAML file with `viewer:` and `operator:` tokens (each a string or a list of strings).
    token_file: str | None = None
    # Trail kept for the page: 2 min at the gyro rate (the page keeps the same).
    trail_samples: int = Field(24_000, ge=100, le=1_000_000)
    reference_samples: int = Field(24_000, ge=100, le=1_000_000)
    vision_samples: int = Field(2_000, ge=10, le=100_000)
    # Most rows in one websocket message: a client that fell behind catches up in such steps.
    max_batch_rows: int = Field(4_000, ge=10, le=100_000)
    # Health: a service whose token is up but whose streams have been silent this long is stale.
    stale_after_s: float = Field(2.0, gt=0.0, le=600.0)
    # Status (health, rates, recorder, diagnostics) pushed to each page this often.
    push_status_period_s: float = Field(0.5, gt=0.0, le=10.0)
    # Largest request body accepted (413 above it, refused before it is read): the API's bodies
    # are a few hundred bytes.
    max_body_bytes: int = Field(65_536, ge=1024, le=16 * 1024 * 1024)
    # A websocket client that has not taken one message within this time is dropped (counted):
    # what waits for it is bounded by this time at the push rate.
    ws_send_timeout_s: float = Field(5.0, gt=0.0, le=120.0)
    # Websocket messages a second to all clients together: each client gets at most this over
    # the number of clients (with 50 clients, 40 a second, each carrying every row since the
    # last); below that rate every state leaves alone as it arrives.
    ws_messages_per_s: float = Field(2_000.0, ge=10.0, le=1_000_000.0)
    # permessage-deflate on the websocket: compressed per client and per message on the event
    # loop that also answers the API, a cost that grows with the clients times the state rate;
    # off, each client takes about 1 kB per state (200 kB/s at 200 Hz).
    ws_per_message_deflate: bool = False
    # How long a recorder command waits for the recorder's reply.
    recorder_timeout_s: float = Field(3.0, gt=0.0, le=60.0)
    # Calibration file (tiplog.calibration YAML) for drawing vision observations in the base frame.
    calibration_file: str | None = None
    # Foxglove live: serve the bus's topics with their schemas on a Foxglove WebSocket server.
    foxglove_bridge: bool = False
    foxglove_host: str = "127.0.0.1"
    foxglove_port: int = Field(8765, ge=0, le=65535)
    # The Foxglove protocol has no authentication: a non-loopback foxglove_host needs this too.
    foxglove_allow_remote: bool = False
    # Topics the bridge serves (key expression under the bus prefix).
    foxglove_topics: str = "**"

    @field_validator("host", "foxglove_host")
    @classmethod
    def _host_shape(cls, v: str) -> str:
        if not v or any(c.isspace() for c in v):
            raise ValueError("must be a host name or IP address")
        return v

    def is_loopback(self) -> bool:
        """True when `host` only accepts connections from this machine."""
        return host_is_loopback(self.host)

    def foxglove_binding_problem(self) -> str | None:
        """Why the Foxglove bridge may not start as configured, or None."""
        if self.foxglove_bridge and not host_is_loopback(self.foxglove_host) and not self.foxglove_allow_remote:
            return (
                f"dashboard: foxglove_host {self.foxglove_host} is not loopback and the Foxglove protocol has no "
                "authentication; set foxglove_allow_remote: true to serve it there anyway"
            )
        return None
