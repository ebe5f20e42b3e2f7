"""Recorder controls for operators: start, stop, mark an event, and the recorder's status.

Each action goes to the recorder's `recorder/command` queryable. Operator actions are logged
with the client's address and recorded in the file as events (a MARK labelled
`dashboard: ...`): after a start (so it lands in the new file) and before a stop.
"""

import logging
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request
from pydantic import BaseModel, ConfigDict, Field

from services.dashboard.auth import Role
from services.dashboard.payload import message_dict
from tiplog import topics
from tiplog.bus import Bus
from tiplog.v1 import recorder_pb2

log = logging.getLogger("tiplog.dashboard")
A = recorder_pb2.RecorderAction

# Printable text without control characters; the recorder writes it into file metadata.
_TEXT = r"^[^\x00-\x1f\x7f]*$"


class StartRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    session: str = Field("", max_length=64, pattern=r"^[A-Za-z0-9_.-]*$", description="session name ('' = automatic)")
    reason: str = Field("", max_length=200, pattern=_TEXT, description="why the recording starts")


class StopRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    reason: str = Field("", max_length=200, pattern=_TEXT)


class MarkRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    label: str = Field(..., min_length=1, max_length=200, pattern=_TEXT, description="event label")


class RecorderReply(BaseModel):
    ok: bool = Field(description="the recorder accepted the command")
    message: str
    status: dict[str, Any] | None = Field(None, description="RecorderStatus after the command")


class RecorderClient:
    """Sends RecorderCommand queries on the bus; None when no recorder answered."""

    def __init__(self, bus: Bus, timeout_s: float = 3.0):
        self.bus = bus
        self.timeout_s = timeout_s

    def command(self, action: int, reason: str = "", session: str = "") -> recorder_pb2.RecorderReply | None:
        cmd = recorder_pb2.RecorderCommand(action=action, reason=reason, session=session)
        replies = self.bus.request(topics.RECORDER_COMMAND, cmd.SerializeToString(), timeout_s=self.timeout_s)
        for raw in replies:
            try:
                return recorder_pb2.RecorderReply.FromString(raw)
            except Exception as e:  # a foreign queryable on the key
                log.warning("recorder reply does not parse: %s", e)
        return None


def _reply(r: recorder_pb2.RecorderReply | None) -> RecorderReply:
    if r is None:
        # 503 is the honest answer to a missing recorder (documented in the schema).
        raise HTTPException(status_code=503, detail="no recorder answered on the bus")
    return RecorderReply(ok=r.ok, message=r.message, status=message_dict(r.status) if r.HasField("status") else None)


def router(client: RecorderClient, require: Callable[[Role], Any]) -> APIRouter:
    """The /api/recorder routes; `require(role)` is the authentication dependency."""
    api = APIRouter(prefix="/api/recorder", tags=["recorder"])
    unavailable = {503: {"description": "no recorder answered on the bus"}}
    denied = {401: {"description": "no valid token"}, 403: {"description": "a viewer token: operators only"}}
    bad_body = {400: {"description": "the body is not JSON"}}

    Viewer = Annotated[Role, Depends(require(Role.VIEWER))]
    Operator = Annotated[Role, Depends(require(Role.OPERATOR))]

    def who(request: Request, role: Role) -> str:
        host = request.client.host if request.client else "?"
        return f"{role.name.lower()} at {host}"

    @api.get("", response_model=RecorderReply, responses={**unavailable, 401: denied[401]})
    def recorder_status(role: Viewer) -> RecorderReply:
        """The recorder's status: state, file, size, duration, free disk, alarm, per-topic counts."""
        return _reply(client.command(A.RECORDER_ACTION_STATUS))

    @api.post("/start", response_model=RecorderReply, responses={**unavailable, **denied, **bad_body})
    def start(body: StartRequest, request: Request, role: Operator) -> RecorderReply:
        """Start a recording (operators). Recorded as an event in the new file."""
        log.info(
            "operator action: start recording (session %r, reason %r) by %s",
            body.session,
            body.reason,
            who(request, role),
        )
        reply = client.command(A.RECORDER_ACTION_START, body.reason or "dashboard", body.session)
        if reply is not None and reply.ok:
            client.command(
                A.RECORDER_ACTION_MARK, f"dashboard: start by {who(request, role)}: {body.reason}".rstrip(": ")
            )
        return _reply(reply)

    @api.post("/stop", response_model=RecorderReply, responses={**unavailable, **denied, **bad_body})
    def stop(body: StopRequest, request: Request, role: Operator) -> RecorderReply:
        """Stop the recording (operators). The event is recorded before the file closes."""
        log.info("operator action: stop recording (reason %r) by %s", body.reason, who(request, role))
        client.command(A.RECORDER_ACTION_MARK, f"dashboard: stop by {who(request, role)}: {body.reason}".rstrip(": "))
        return _reply(client.command(A.RECORDER_ACTION_STOP, body.reason or "dashboard"))

    @api.post("/mark", response_model=RecorderReply, responses={**unavailable, **denied, **bad_body})
    def mark(body: MarkRequest, request: Request, role: Operator) -> RecorderReply:
        """Mark an event in the recording (operators)."""
        log.info("operator action: mark %r by %s", body.label, who(request, role))
        return _reply(client.command(A.RECORDER_ACTION_MARK, body.label))

    return api
