"""Access tokens: viewer (read only) and operator (read + recorder controls).

Tokens come from the environment (`TIPLOG_DASHBOARD_VIEWER_TOKEN`,
`TIPLOG_DASHBOARD_OPERATOR_TOKEN`, comma-separated for several) or from a YAML file
(`viewer:` / `operator:`, each a string or a list), never from the command line. On loopback
without any token every local client is an operator (the surgeon's own screen); bound to any
other address the dashboard refuses to start without both kinds.

A client presents its token as `Authorization: Bearer <token>` or in the `tiplog_token`
cookie that the login form sets (HttpOnly, SameSite=Strict).
"""

from __future__ import annotations

import hmac
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import yaml

from tiplog.userio import UserError, input_file

ENV_VIEWER = "TIPLOG_DASHBOARD_VIEWER_TOKEN"
ENV_OPERATOR = "TIPLOG_DASHBOARD_OPERATOR_TOKEN"
COOKIE = "tiplog_token"
MIN_TOKEN_CHARS = 16
log = logging.getLogger("tiplog.dashboard")


class Role(IntEnum):
    NONE = 0
    VIEWER = 1
    OPERATOR = 2


@dataclass(frozen=True)
class Tokens:
    viewer: tuple[str, ...] = ()
    operator: tuple[str, ...] = ()

    @property
    def enabled(self) -> bool:
        return bool(self.viewer or self.operator)

    def role_of(self, token: str | None) -> Role:
        """The role a presented token grants (constant-time comparisons); NONE when it is
        invalid. With no tokens configured (loopback only), everyone is an operator."""
        if not self.enabled:
            return Role.OPERATOR
        if not token:
            return Role.NONE
        given = token.encode()
        role = Role.NONE
        for t in self.operator:
            if hmac.compare_digest(given, t.encode()):
                role = Role.OPERATOR
        for t in self.viewer:
            if hmac.compare_digest(given, t.encode()) and role < Role.VIEWER:
                role = Role.VIEWER
        return role


def _as_list(value: object, where: str) -> list[str]:
    if value is None:
        return []
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(t, str) for t in items):
        raise UserError(f"{where}: must be a token string or a list of token strings")
    out = [t.strip() for t in items if t.strip()]
    for t in out:
        if len(t) < MIN_TOKEN_CHARS:
            raise UserError(f"{where}: a token is shorter than {MIN_TOKEN_CHARS} characters")
    return out


def load_tokens(token_file: str | None, env: Mapping[str, str] | None = None) -> Tokens:
    """Tokens from the environment and `token_file` together; UserError names a bad source."""
    env = os.environ if env is None else env
    viewer = _as_list([t for t in env.get(ENV_VIEWER, "").split(",")], ENV_VIEWER)
    operator = _as_list([t for t in env.get(ENV_OPERATOR, "").split(",")], ENV_OPERATOR)
    if token_file:
        p = input_file(token_file, "token file")
        if p.stat().st_mode & 0o077:
            # Readable by others: say so, but a cart image may legitimately ship it 0644.
            log.warning("token file %s is readable by other users", p)
        try:
            doc = yaml.safe_load(Path(p).read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as e:
            raise UserError(f"{p}: not a valid YAML token file ({e.__class__.__name__})") from None
        if not isinstance(doc, dict) or not set(doc) <= {"viewer", "operator"}:
            raise UserError(f"{p}: expected a mapping with 'viewer' and/or 'operator'")
        viewer += _as_list(doc.get("viewer"), f"{p}: viewer")
        operator += _as_list(doc.get("operator"), f"{p}: operator")
    overlap = set(viewer) & set(operator)
    if overlap:
        raise UserError("a token is listed both as viewer and as operator")
    return Tokens(tuple(viewer), tuple(operator))


def check_binding(loopback: bool, host: str, tokens: Tokens) -> None:
    """Refuse to serve a non-loopback address without both a viewer and an operator token."""
    if loopback:
        return
    missing = [k for k, v in (("viewer", tokens.viewer), ("operator", tokens.operator)) if not v]
    if missing:
        raise UserError(
            f"dashboard: host {host} is not loopback and no {' or '.join(missing)} token is set; "
            f"give tokens in {ENV_VIEWER} / {ENV_OPERATOR} or in a token_file"
        )


def bearer(authorization: str | None) -> str | None:
    """The token of an `Authorization: Bearer <token>` header, else None."""
    if not authorization:
        return None
    scheme, _, value = authorization.partition(" ")
    return value.strip() if scheme.lower() == "bearer" and value.strip() else None
