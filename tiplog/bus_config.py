"""Where a bus session connects and listens, its key prefix, and TLS: `BusConfig`, the `bus:`
section every service shares (see tiplog.bus for the session itself)."""

from __future__ import annotations

import ipaddress
import json
import re
from pathlib import Path
from typing import Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
PROTOCOLS = ("tcp", "udp", "tls", "quic", "unixsock-stream", "ws")
_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"  # with "_", as container names have
_HOST_NAME = re.compile(rf"{_LABEL}(?:\.{_LABEL})*\.?")


def endpoint_problem(endpoint: str, listening: bool = False) -> str | None:
    """Why `endpoint` cannot be a Zenoh endpoint (PROTO/HOST:PORT, HOST a name, an IPv4
    address or a bracketed IPv6 one; port 1-65535, or 0 to listen on any free one), or None.
    Zenoh itself takes `tcp/999.1.1.1:1` and retries it for ever."""
    form = f"endpoint {endpoint!r} is not of the form 'tcp/HOST:PORT'"
    proto, slash, rest = endpoint.partition("/")
    if not slash or proto not in PROTOCOLS:
        return form
    if proto == "unixsock-stream":
        return None if rest else f"endpoint {endpoint!r}: no socket path"
    addr = re.split(r"[?#]", rest, maxsplit=1)[0]  # zenoh's ?metadata and #configuration suffixes
    host, colon, port = addr.rpartition(":")
    if not colon or not host or not port.isdigit():
        return form
    lo = 0 if listening else 1
    if not lo <= int(port) <= 65535:
        return f"endpoint {endpoint!r}: port {int(port)} is not in {lo}-65535"
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return f"endpoint {endpoint!r}: {host} is not an IPv6 address"
    elif re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f"endpoint {endpoint!r}: {host} is not an IPv4 address (four numbers 0-255)"
    elif len(host) > 253 or not _HOST_NAME.fullmatch(host):
        return f"endpoint {endpoint!r}: {host!r} is not a host name or address"
    return None


class BusConfig(BaseModel):
    """Where the Zenoh session connects, listens, and which key prefix it uses."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    connect: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    # Peers learn of each other through the router (gossip) but exchange data directly, so a
    # peer must listen somewhere: an ephemeral loopback port by default. A service on another
    # machine (or in its own container) uses mode "client" and reaches everything through
    # the router it connects to.
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:0"])
    prefix: str = "tiplog/"
    multicast_scouting: bool = False
    # Shared memory for large payloads between processes on one host (zenoh default: on).
    shared_memory: bool = True
    # A client cannot open until its router answers: retry this long, None = until stopped
    # (compose starts the router and the services together; a cart boots them in any order).
    # Either way the process says within NOTICE_AFTER_S that nothing answers, and where.
    open_timeout_s: float | None = Field(None, ge=0.0, le=86400.0)
    # Peer mode only: when nothing listens at the first loopback endpoint of `connect`, listen
    # there too, so tiplog processes started alone on one machine (`tiplog replay` and
    # `tiplog record run` in two terminals) find each other without `tiplog up`.
    standalone: bool = False
    # TLS (endpoints `tls/HOST:PORT`): the CA that signed the router's certificate, and on the
    # side that listens (the cart's router) its certificate and private key; PEM files. See
    # docs/deployment.md for the command that makes them.
    tls_root_ca: str | None = None
    tls_certificate: str | None = None
    tls_private_key: str | None = None

    @field_validator("prefix")
    @classmethod
    def _prefix_shape(cls, v: str) -> str:
        if not v or not v.endswith("/") or v.startswith("/") or any(c in v for c in "*$#?"):
            raise ValueError("must be a key prefix ending in '/', e.g. 'tiplog/'")
        return v

    @field_validator("tls_root_ca", "tls_certificate", "tls_private_key")
    @classmethod
    def _pem_file(cls, v: str | None) -> str | None:
        if v is not None and not Path(v).is_file():
            raise ValueError(f"no such file {v!r} (a PEM file)")
        return v

    @model_validator(mode="after")
    def _tls_pair(self) -> BusConfig:
        if bool(self.tls_certificate) != bool(self.tls_private_key):
            raise ValueError("tls_certificate and tls_private_key go together")
        uses_tls = any(e.startswith("tls/") for e in self.connect + self.listen)
        if uses_tls and not self.tls_root_ca:
            raise ValueError("a tls/ endpoint needs tls_root_ca (the CA that signed the router's certificate)")
        if any(e.startswith("tls/") for e in self.listen) and not self.tls_certificate:
            raise ValueError("listening on a tls/ endpoint needs tls_certificate and tls_private_key")
        return self

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, v: list[str], info: ValidationInfo) -> list[str]:
        for e in v:
            why = endpoint_problem(e, listening=info.field_name == "listen")
            if why:
                raise ValueError(why)
        return v

    def zenoh_config(self) -> zenoh.Config:
        """The zenoh.Config this bus configuration stands for."""
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(self.shared_memory))
        tls = {
            "root_ca_certificate": self.tls_root_ca,
            "listen_certificate": self.tls_certificate,
            "listen_private_key": self.tls_private_key,
        }
        for key, path in tls.items():
            if path:
                conf.insert_json5(f"transport/link/tls/{key}", json.dumps(path))
        return conf
