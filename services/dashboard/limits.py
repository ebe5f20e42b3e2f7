"""What the dashboard accepts from a client, and the answers to what it refuses: never a 5xx.

- `BodyLimit`: an ASGI middleware that refuses a request body over `max_body_bytes` with 413
  before reading it (a Content-Length over the limit), or as soon as a body without one
  (chunked) passes the limit; nothing over the limit is held in memory.
- `validation_error`: the 422 for a body that does not validate, built from the error's type,
  location and message only, each made valid UTF-8 (the default handler echoes the input,
  which may hold undecodable bytes or lone surrogates that cannot be encoded).
"""

from __future__ import annotations

import json
from typing import Any

from fastapi import HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


def clean_text(value: object) -> str:
    """`value` as text that encodes as UTF-8: lone surrogates and undecodable bytes escaped."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "backslashreplace")
    return str(value).encode("utf-8", "backslashreplace").decode("utf-8")


async def validation_error(_request: Request, exc: Exception) -> JSONResponse:
    """422 with FastAPI's shape (detail: [{type, loc, msg}]) and nothing the client sent."""
    errors = exc.errors() if isinstance(exc, RequestValidationError) else []
    detail = [
        {
            "type": clean_text(e.get("type", "value_error")),
            "loc": [x if isinstance(x, int) else clean_text(x) for x in e.get("loc", ())],
            "msg": clean_text(e.get("msg", "invalid")),
        }
        for e in errors
    ]
    return JSONResponse({"detail": detail}, status_code=422)


class _TooLarge(HTTPException):
    """Raised from `receive` inside a route's body parsing: FastAPI passes HTTPExceptions on."""

    def __init__(self, limit: int):
        super().__init__(413, f"request body over the limit of {limit} bytes")


class BodyLimit:
    """Refuse request bodies over `max_body_bytes` with 413 (HTTP only; websockets pass)."""

    def __init__(self, app: ASGIApp, max_body_bytes: int):
        self.app = app
        self.max_body_bytes = max_body_bytes

    def _refusal(self) -> bytes:
        return json.dumps({"detail": f"request body over the limit of {self.max_body_bytes} bytes"}).encode()

    async def _send_413(self, send: Send) -> None:
        body = self._refusal()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        await send({"type": "http.response.start", "status": 413, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = _content_length(scope)
        if length is not None and length > self.max_body_bytes:
            await self._send_413(send)
            return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_body_bytes:
                    raise _TooLarge(self.max_body_bytes)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _TooLarge:
            if not started:
                await self._send_413(send)


def _content_length(scope: Scope) -> int | None:
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


def install(app: Any, max_body_bytes: int) -> None:
    """The limit and the 422 handler on a FastAPI `app`."""
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_middleware(BodyLimit, max_body_bytes=max_body_bytes)
