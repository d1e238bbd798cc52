"""Dependencies of the routes, as ``Annotated`` aliases (FastAPI template style)."""

from __future__ import annotations

import secrets
from typing import Annotated

from celery import Celery
from fastapi import Depends, HTTPException, Request, status

from services.farm.blobs import BlobStore
from services.farm.records import Records
from services.farm.settings import Settings
from services.farm.store import JobStore


# The dependencies are ``async``: they do no I/O, and FastAPI runs a plain ``def`` dependency in
# its thread pool, a hand-off that cost more than the rest of a status request together.
async def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


async def get_store(request: Request) -> JobStore:
    return request.app.state.store


async def get_celery(request: Request) -> Celery:
    return request.app.state.celery


SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
StoreDep = Annotated[JobStore, Depends(get_store)]
CeleryDep = Annotated[Celery, Depends(get_celery)]


async def get_blobs(request: Request) -> BlobStore:
    return request.app.state.blobs


BlobsDep = Annotated[BlobStore, Depends(get_blobs)]


async def get_records(request: Request) -> Records:
    return request.app.state.records


RecordsDep = Annotated[Records, Depends(get_records)]


async def get_submitter(request: Request) -> str | None:
    """The name of the API token the request came with (``LUCENT_API_TOKENS``), if any."""
    return getattr(request.state, "token_name", None)


SubmitterDep = Annotated[str | None, Depends(get_submitter)]


async def require_token(request: Request, settings: SettingsDep) -> None:
    """With ``LUCENT_API_TOKEN`` or ``LUCENT_API_TOKENS`` set, ``Authorization: Bearer <token>``
    (compared in constant time with every token; a named one's name is kept on the request);
    without either, the API is open (development on one machine)."""
    tokens = {**settings.api_tokens, "": settings.api_token or ""}
    if not any(tokens.values()):
        return
    scheme, _, given = request.headers.get("authorization", "").partition(" ")
    matches = [name for name, token in tokens.items()
               if token and secrets.compare_digest(given.strip().encode(), token.encode())]
    if scheme.lower() == "bearer" and matches:
        request.state.token_name = matches[0] or None
    else:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            detail="missing or wrong API token (Authorization: Bearer <LUCENT_API_TOKEN>)",
            headers={"WWW-Authenticate": "Bearer"},
        )
