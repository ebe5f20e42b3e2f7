"""The dashboard's web application: the page, its websocket, and the JSON API.

Every route but `/login` needs a valid token when tokens are configured (401 otherwise, and
the websocket closes with 1008); recorder actions need an operator token (403 for a viewer).
The page's script and style come from this server (no CDN) and the Content-Security-Policy
allows nothing else; the page writes bus data with `textContent` and canvas calls only.
"""

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import parse_qs

# anyio imports its file API lazily, on the first static file served, in the server's thread:
# imported here, at start, instead (under pytest's import hook that late import once hit a
# CPython 3.11 bug when two threads parse source at once: "AST constructor recursion depth
# mismatch", and the page's request got no body)
from anyio import open_file as _open_file  # noqa: F401
from fastapi import Depends, FastAPI, HTTPException, Request, WebSocket
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response
from fastapi.security import APIKeyCookie, HTTPAuthorizationCredentials, HTTPBearer
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.dashboard import limits, payload
from services.dashboard.auth import COOKIE, Role, Tokens, bearer
from services.dashboard.config import DashboardConfig
from services.dashboard.feed import BusFeed
from services.dashboard.metrics_api import router as metrics_router
from services.dashboard.recorder_api import RecorderClient, router
from services.dashboard.websocket import BatchCache, Wake, serve_client

log = logging.getLogger("tiplog.dashboard")
STATIC = Path(__file__).with_name("static")
STATIC_FILES = {
    "dashboard.js": "text/javascript",
    "dashboard.css": "text/css",
    "draw.js": "text/javascript",
    "favicon.svg": "image/svg+xml",
}
CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
    "base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
LOGIN_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>tiplog dashboard: sign in</title></head>
<body><h1>tiplog dashboard</h1><p>{message}</p>
<form method="post" action="/login"><label>Token <input type="password" name="token" autocomplete="off"
 id="token"></label> <button type="submit" id="sign-in">Sign in</button></form></body></html>
"""


def same_origin(origin: str, conn: Any) -> bool:
    """True when an Origin header names the host the request was sent to."""
    return origin.split("://", 1)[-1] == conn.headers.get("host", "")


SECURITY_HEADERS = [
    (b"content-security-policy", CSP.encode()),
    (b"x-content-type-options", b"nosniff"),
    # same-origin, not no-referrer: with no-referrer Chromium sends "Origin: null" on the
    # page's own form posts, which the cross-site check would refuse.
    (b"referrer-policy", b"same-origin"),
    (b"cache-control", b"no-store"),
]


class SecurityHeaders:
    """Refuses cross-site writes and adds the security headers to every HTTP response. Plain
    ASGI, not `@app.middleware("http")`: that one runs each request through extra tasks and
    streams, hops on an event loop that also serves every websocket client."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                names = {k for k, _ in SECURITY_HEADERS}
                message["headers"] = [h for h in message.get("headers", []) if h[0].lower() not in names]
                message["headers"] += SECURITY_HEADERS
            await send(message)

        conn = HTTPConnection(scope)
        origin_hdr = conn.headers.get("origin")
        if scope["method"] not in ("GET", "HEAD", "OPTIONS") and origin_hdr and not same_origin(origin_hdr, conn):
            # Another site's page posting with the operator's cookie (or to a token-less loopback
            # dashboard): refused before any route runs.
            refusal = Response("cross-site request refused", status_code=403, media_type="text/plain")
            await refusal(scope, receive, send_with_headers)
            return
        await self.app(scope, receive, send_with_headers)


_bearer = HTTPBearer(auto_error=False, description="viewer or operator token")
_cookie = APIKeyCookie(name=COOKIE, auto_error=False, description="token set by POST /login")


def create_app(feed: BusFeed, config: DashboardConfig, tokens: Tokens, recorder: RecorderClient) -> FastAPI:
    """The FastAPI application around `feed` (already subscribed on the bus)."""
    wake: dict[str, Wake] = {}
    feed.batch_cache = BatchCache()

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        w = Wake(asyncio.get_running_loop())
        wake["w"] = w
        feed.add_listener(w.from_thread)
        try:
            yield
        finally:
            feed.remove_listener(w.from_thread)

    app = FastAPI(
        title="tiplog dashboard",
        version="1",
        description="Live state of the instrument, service health and recorder controls. Every route needs a "
        "viewer or operator token (Authorization: Bearer, or the cookie POST /login sets) unless the dashboard "
        "runs on loopback without tokens.",
        docs_url=None,  # Swagger UI would load from a CDN: the schema is at /openapi.json
        redoc_url=None,
        openapi_url=None,  # served below, behind the token like everything else
        lifespan=lifespan,
    )

    limits.install(app, config.max_body_bytes)

    def role_of(authorization: str | None, cookie: str | None) -> Role:
        return tokens.role_of(bearer(authorization) or cookie)

    def require(minimum: Role):
        # async: checked on the event loop, no hop to the thread pool for every request
        async def dependency(
            creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
            cookie: Annotated[str | None, Depends(_cookie)],
        ) -> Role:
            role = tokens.role_of((creds.credentials if creds else None) or cookie)
            if role == Role.NONE:
                raise HTTPException(401, "a valid token is needed", headers={"WWW-Authenticate": "Bearer"})
            if role < minimum:
                raise HTTPException(403, "this needs an operator token")
            return role

        return dependency

    Viewer = Annotated[Role, Depends(require(Role.VIEWER))]

    app.add_middleware(SecurityHeaders)

    @app.post("/logout", include_in_schema=False)
    def logout() -> Response:
        resp = RedirectResponse("/", status_code=303)
        resp.delete_cookie(COOKIE, path="/")
        return resp

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index(request: Request) -> Response:
        if role_of(request.headers.get("authorization"), request.cookies.get(COOKIE)) == Role.NONE:
            return HTMLResponse(LOGIN_PAGE.format(message="A token is needed."), status_code=401)
        return FileResponse(STATIC / "index.html", media_type="text/html")

    @app.post("/login", include_in_schema=False)
    async def login(request: Request) -> Response:
        form = parse_qs((await request.body())[:4096].decode(errors="replace"))
        token = (form.get("token") or [""])[0].strip()
        if tokens.role_of(token) == Role.NONE:
            log.warning("rejected sign-in from %s", request.client.host if request.client else "?")
            return HTMLResponse(LOGIN_PAGE.format(message="That token is not valid."), status_code=401)
        resp = RedirectResponse("/", status_code=303)
        secure = request.url.scheme == "https"
        resp.set_cookie(COOKIE, token, httponly=True, samesite="strict", path="/", secure=secure)
        return resp

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> Response:
        # Asked for by every browser, the sign-in page's too: nothing to protect in an icon.
        return FileResponse(STATIC / "favicon.svg", media_type="image/svg+xml")

    @app.get("/static/{name}", include_in_schema=False)
    def static(name: str, _role: Viewer) -> Response:
        if name not in STATIC_FILES:
            raise HTTPException(404, "no such file")
        return FileResponse(STATIC / name, media_type=STATIC_FILES[name])

    @app.get("/api/state", tags=["live"])
    async def api_state(_role: Viewer) -> dict[str, Any]:
        """The newest fusion state (tiplog.v1.FusionState as JSON), its derived row (tip in mm,
        error against the reference), how many states were received and the newest's age."""
        return payload.state_now(feed, feed.t0_ns)

    @app.get("/api/health", tags=["live"])
    async def api_health(_role: Viewer) -> dict[str, Any]:
        """Services by liveliness token (up, stale, down) and per-stream rates and drops."""
        return {"services": feed.health.snapshot(), "streams": feed.streams.snapshot()}

    @app.get("/api/status", tags=["live"])
    async def api_status(_role: Viewer) -> dict[str, Any]:
        """Everything the page shows besides the trails (what the websocket pushes)."""
        return payload.status(feed, feed.t0_ns)

    @app.get(
        "/api/preview",
        tags=["live"],
        response_class=Response,
        responses={200: {"content": {"image/jpeg": {}, "image/png": {}}}, 404: {"description": "no preview yet"}},
    )
    def api_preview(_role: Viewer) -> Response:
        """The newest vision preview image."""
        p = feed.preview
        if p is None:
            raise HTTPException(404, "no vision preview received yet")
        return Response(p[2], media_type=f"image/{p[1]}")

    app.include_router(router(recorder, require))
    app.include_router(metrics_router(feed, require))

    @app.get("/openapi.json", include_in_schema=False)
    def openapi(_role: Viewer) -> dict[str, Any]:
        return app.openapi()

    @app.websocket("/ws")
    async def ws(websocket: WebSocket) -> None:
        role = role_of(websocket.headers.get("authorization"), websocket.cookies.get(COOKIE))
        origin_hdr = websocket.headers.get("origin")
        if origin_hdr and not same_origin(origin_hdr, websocket):
            role = Role.NONE  # another site's page: cookies must not open the stream
        if role == Role.NONE:
            await websocket.close(code=1008)
            return
        await websocket.accept()
        await serve_client(websocket, feed, wake["w"], config, feed.t0_ns, role.name.lower())

    return app
