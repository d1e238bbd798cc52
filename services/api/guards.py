"""What guards the app from hostile requests before and after the routes run.

- ``BodyLimit``: a request body over ``LUCENT_MAX_BODY_BYTES`` is refused with 413, whether it
  declares its length (``Content-Length``, refused before a byte is read) or streams it
  (``Transfer-Encoding: chunked``, refused as soon as the bytes read pass the limit), so a client
  cannot make the service buffer an unbounded body by leaving the length out.
- ``validation_error`` and ``error_content``: a 4xx that names what was wrong echoes a bounded,
  encodable copy of it (``echo``), whatever the client sent: FastAPI's 422 echoes the offending
  ``input`` in full and encodes it recursively, so a 50 MB ``name`` made a 50 MB reply and a list
  nested 500 deep inside a request-level field a RecursionError (500). Python's JSON parser also
  accepts what the strict JSON encoder of the response refuses: ``NaN``, ``Infinity`` and
  ``-Infinity`` (and reads ``1e400`` as infinity), echoed as those literals' names, and lone UTF-16
  surrogates (``"\\ud800"``), which no UTF-8 reply can hold, echoed as their escape. Every text of
  an error (``loc`` parts, ``msg``, ``input``, ``ctx``) goes through the same rules.
- ``store_unavailable``: Redis down, restarting or cut off is 503 with ``Retry-After`` and the
  kind of failure (``services.farm.availability``), not a bare 500 whose log names its address.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Iterable
from typing import Any

from fastapi import HTTPException, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.farm.availability import RETRY_AFTER, unavailable_detail

log = logging.getLogger(__name__)


def _too_large(size: str, limit: int) -> str:
    return f"request body of {size} bytes exceeds the limit {limit} (LUCENT_MAX_BODY_BYTES)"


class BodyLimit:
    """ASGI middleware: 413 for a request body over ``max_bytes``."""

    def __init__(self, app: ASGIApp, max_bytes: int,
                 paths: dict[str, int] | None = None) -> None:
        self.app = app
        self.default_bytes = max_bytes
        self.paths = paths or {}  # a limit of their own for these paths (uploads)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        max_bytes = self.paths.get(scope.get("path", ""), self.default_bytes)
        headers = dict(scope["headers"])
        length = headers.get(b"content-length", b"").decode("latin-1")
        if length.isdigit() and int(length) > max_bytes:
            await JSONResponse(status_code=status.HTTP_413_CONTENT_TOO_LARGE,
                               content={"detail": _too_large(length, max_bytes)}
                               )(scope, receive, send)
            return

        received = 0

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    # FastAPI re-raises an HTTPException met while reading the body; its handler
                    # answers 413 (and so does the fallback below for any other reader).
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                                        detail=_too_large(f"more than {max_bytes}", max_bytes))
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


# How much of a client's input an error echoes: enough to recognise it, never all of it.
ECHO_CHARS = 200  # characters of a text (a msg, a loc part, a string input)
ECHO_ITEMS = 10  # items of a list or an object
ECHO_DEPTH = 3  # levels of lists and objects; deeper ones are summarised


def echo_text(text: str, limit: int = ECHO_CHARS) -> str:
    """``text`` cut to ``limit`` characters (saying how long it was), lone surrogates escaped."""
    if len(text) > limit:
        text = f"{text[:limit]}… ({len(text)} characters)"
    # A lone surrogate (\ud800 in JSON) is no Unicode character: UTF-8 cannot encode it.
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def echo(value: Any, depth: int = ECHO_DEPTH) -> Any:
    """A bounded copy of ``value`` that the strict JSON encoder accepts: texts cut and escaped
    (``echo_text``), non-finite floats as their literals' names, at most ``ECHO_ITEMS`` items a
    container and ``depth`` levels (the rest summarised). Never recursive beyond ``depth``, so
    any nesting the parser accepted is echoed in bounded time and stack."""
    if value is None or isinstance(value, bool | int):
        if isinstance(value, int) and value.bit_length() > 256:  # past 77 digits: its size
            return f"an integer of {value.bit_length()} bits"
        return value
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, str):
        return echo_text(value)
    if isinstance(value, dict | list | tuple):
        n = len(value)
        if depth == 0:
            kind = "an object" if isinstance(value, dict) else "a list"
            return f"{kind} of {n} item{'' if n == 1 else 's'}"
        if isinstance(value, dict):
            out = {echo_text(str(k)): echo(v, depth - 1)
                   for k, v in itertools.islice(value.items(), ECHO_ITEMS)}
            if n > ECHO_ITEMS:
                out["…"] = f"{n - ECHO_ITEMS} more items"
            return out
        items = [echo(v, depth - 1) for v in itertools.islice(value, ECHO_ITEMS)]
        if n > ECHO_ITEMS:
            items.append(f"… {n - ECHO_ITEMS} more items")
        return items
    return echo_text(str(value))  # an exception in ctx, bytes, ...


def echo_error(error: dict[str, Any]) -> dict[str, Any]:
    """One error of a 4xx ``detail`` (pydantic's or ours: ``loc``, ``msg``, ``type``, maybe
    ``input`` and ``ctx``), every part bounded and encodable; pydantic's ``url`` left out."""
    out: dict[str, Any] = {
        "loc": [p if isinstance(p, int) else echo_text(str(p)) for p in error.get("loc", ())],
        "msg": echo_text(str(error.get("msg", "")), 4 * ECHO_CHARS),
        "type": echo_text(str(error.get("type", ""))),
    }
    if "input" in error:
        out["input"] = echo(error["input"])
    if error.get("ctx"):
        out["ctx"] = {echo_text(str(k)): echo(v, 1) for k, v in error["ctx"].items()}
    return out


def error_content(errors: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """``{"detail": [...]}`` of a 4xx that names fields, safe to encode (``echo_error``); an
    unknown field is said in the scene's words."""
    return {"detail": [echo_error({**e, "msg": "unknown field"}
                                  if e.get("type") == "extra_forbidden" else e)
                       for e in errors]}


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 for an invalid request, safe to encode whatever the client sent."""
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
                        content=error_content(exc.errors()))


async def store_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """503 for a route whose Redis call failed because Redis cannot be reached now."""
    return JSONResponse(status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                        headers={"Retry-After": str(RETRY_AFTER)},
                        content={"detail": unavailable_detail(exc)})


async def database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """503 for a route whose job database (``services.farm.records``) does not answer now."""
    log.warning("the job database is unavailable: %s", exc)
    return JSONResponse(status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                        headers={"Retry-After": str(RETRY_AFTER)},
                        content={"detail": "the farm's job database is unavailable; try again "
                                           "shortly"})
