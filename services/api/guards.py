"""What guards the app from hostile requests before and after the routes run.

- ``BodyLimit``: a request body over ``LUCENT_MAX_BODY_BYTES`` is refused with 413, whether it
  declares its length (``Content-Length``, refused before a byte is read) or streams it
  (``Transfer-Encoding: chunked``, refused as soon as the bytes read pass the limit), so a client
  cannot make the service buffer an unbounded body by leaving the length out.
- ``validation_error``: FastAPI's 422 for a malformed request echoes the offending ``input``;
  Python's JSON parser accepts the non-standard literals ``NaN``, ``Infinity`` and ``-Infinity``
  (and reads ``1e400`` as infinity), which the strict JSON encoder of the response refuses, turning
  a client's error into a 500. Non-finite numbers are echoed as those literals' names instead.
"""

from __future__ import annotations

import math
from typing import Any

from fastapi import HTTPException, Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


def _too_large(size: str, limit: int) -> str:
    return f"request body of {size} bytes exceeds the limit {limit} (LUCENT_MAX_BODY_BYTES)"


class BodyLimit:
    """ASGI middleware: 413 for a request body over ``max_bytes``."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        length = headers.get(b"content-length", b"").decode("latin-1")
        if length.isdigit() and int(length) > self.max_bytes:
            await JSONResponse(status_code=status.HTTP_413_CONTENT_TOO_LARGE,
                               content={"detail": _too_large(length, self.max_bytes)}
                               )(scope, receive, send)
            return

        received = 0

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    # FastAPI re-raises an HTTPException met while reading the body; its handler
                    # answers 413 (and so does the fallback below for any other reader).
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                                        detail=_too_large(f"more than {self.max_bytes}",
                                                          self.max_bytes))
            return message

        started = False

        async def tracked_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted_receive, tracked_send)
        except HTTPException as err:
            if started or err.status_code != status.HTTP_413_CONTENT_TOO_LARGE:
                raise
            await JSONResponse(status_code=err.status_code, content={"detail": err.detail}
                               )(scope, receive, send)


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by its JSON literal's name."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 for an invalid request, safe to encode whatever the client sent."""
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
                        content={"detail": _finite(jsonable_encoder(exc.errors()))})
