"""Who may call the service: the bearer token of every ``/api`` request (``?token=`` on the
live stream) and the same-origin rule. No CORS headers are ever sent and requests from a
browser page of another origin are refused, so a web page cannot drive the service."""

from __future__ import annotations

import hmac
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send


def authorised(token: str | None, header: str | None, query: str | None) -> bool:
    """The request carries ``token`` (always true when the service has none)."""
    if token is None:
        return True
    given = query
    if header and header.lower().startswith("bearer "):
        given = header[7:].strip()
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def same_origin(origin: str | None, host: str | None) -> bool:
    """A browser sends ``Origin``; only pages the service served itself may call it."""
    if not origin:
        return True
    return urlsplit(origin).netloc == (host or "")


class AccessGuard:
    """Token and origin checks of every ``/api`` HTTP request (plain ASGI: no extra task
    or body queue per request, unlike ``BaseHTTPMiddleware``)."""

    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["path"].startswith("/api"):
            headers = Headers(scope=scope)
            refusal = None
            if not authorised(self.token, headers.get("authorization"), None):
                refusal = JSONResponse(
                    {"detail": "missing or wrong bearer token"},
                    status_code=401,
                    headers={"WWW-Authenticate": "Bearer"},
                )
            elif not same_origin(headers.get("origin"), headers.get("host")):
                refusal = JSONResponse({"detail": "cross-origin requests are refused"}, 403)
            if refusal is not None:
                await refusal(scope, receive, send)
                return
        await self.app(scope, receive, send)
