"""Reading a job submission off the event loop, so that ``/healthz`` and the status routes answer
while a large scene is parsed and validated.

FastAPI parses a JSON body with ``json.loads`` on the event loop. A thread does not help:
``json.loads`` and ``json.dumps`` are C code that holds the GIL from start to end, and so does
pydantic-core over one large list; measured on a 47 MB scene, a thread that wakes every
millisecond waited 1.6 s during ``json.loads`` and 0.28 s during ``load_scene``, and ``/healthz``
took up to 1.05 s during the submission. So ``POST /api/jobs`` reads the raw body itself and
hands it to ``read_submission``:

- bodies up to ``LUCENT_INTAKE_INLINE_BYTES`` (1 MiB) in the route's thread pool: their parse is
  a few milliseconds, less than starting anything;
- larger ones in a process of their own (a ``ProcessPoolExecutor`` of
  ``LUCENT_INTAKE_PROCESSES``, started at the first large body and kept): the bytes go there and
  the checked scene's JSON comes back, two copies; the event loop only waits on a future.

``read_submission`` answers as FastAPI's own body handling did: a body that is not JSON is 422
``json_invalid`` (400 when the parser gives up, 10 000 levels deep), a missing one 422
``missing``, an invalid field 422 naming it under ``body``; every echo bounded
(``guards.error_content``) where the work runs, so that no large or deep input crosses back.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from email.message import Message
from typing import Any

from fastapi import status
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from renderer.scene import Limits
from services.api.guards import error_content
from services.api.models import JobCreate
from services.farm.jobs import CheckedScene, JobOptions, Refusal, check_scene


@dataclass(frozen=True)
class Submission:
    """A request whose fields and scene were accepted: what ``queue_job`` takes."""

    options: JobOptions
    scene: CheckedScene


@dataclass(frozen=True)
class Rejection:
    """A request refused before planning: its HTTP status and JSON content, bounded."""

    status: int
    content: dict[str, Any]


def _is_json(content_type: str | None) -> bool:
    """As FastAPI decides: no Content-Type, or application/json or application/*+json."""
    if not content_type:
        return True
    message = Message()
    message["content-type"] = content_type
    main, _, sub = message.get_content_type().partition("/")
    return main == "application" and (sub == "json" or sub.endswith("+json"))


def read_submission(body: bytes, content_type: str | None, limits: Limits,
                    blob_root: str | None = None, packet: bool = False) -> Submission | Rejection:
    """Parse and check a ``POST /api/jobs`` body: JSON, then ``JobCreate``, then the scene
    (``packet``: and whether the packet kernel covers it, ``check_scene``)."""
    # Parse
    if not body:
        data: Any = None
    elif not _is_json(content_type):
        data = body  # as FastAPI: a body that is not JSON is refused by the model below
    else:
        try:
            data = json.loads(body)
        except json.JSONDecodeError as err:
            return Rejection(status.HTTP_422_UNPROCESSABLE_CONTENT, error_content([{
                "type": "json_invalid", "loc": ("body", err.pos), "msg": "JSON decode error",
                "input": {}, "ctx": {"error": err.msg}}]))
        except Exception:  # nested past the parser's limit (RecursionError), not UTF-8, ...
            return Rejection(status.HTTP_400_BAD_REQUEST,
                             {"detail": "There was an error parsing the body"})
    if data is None:
        return Rejection(status.HTTP_422_UNPROCESSABLE_CONTENT, error_content([{
            "type": "missing", "loc": ("body",), "msg": "Field required", "input": None}]))
    # The request's fields
    try:
        create = JobCreate.model_validate(data)
    except ValidationError as err:
        return Rejection(status.HTTP_422_UNPROCESSABLE_CONTENT, error_content(
            {**e, "loc": ("body", *e["loc"])} for e in err.errors(include_url=False)))
    # The scene
    checked = check_scene(create.scene, limits, blob_root, create.frames, packet)
    if isinstance(checked, Refusal):
        return Rejection(checked.status, error_content(
            {"loc": loc, "msg": msg, "type": kind} for loc, msg, kind in checked.errors))
    options = JobOptions(name=create.name, priority=create.priority, tile_size=create.tile_size,
                         spp_per_pass=create.spp_per_pass,
                         max_spp_per_pass=create.max_spp_per_pass,
                         tags=tuple(sorted(set(create.tags))),
                         check_workers=create.check_workers, denoise=create.denoise)
    return Submission(options, checked)


class Intake:
    """Where ``read_submission`` runs: the calling thread pool for bodies up to ``inline_bytes``,
    else ``processes`` processes of its own, started on first use (spawned: the service's
    threads and connections stay behind)."""

    def __init__(self, inline_bytes: int, processes: int, blob_root: str | None = None,
                 packet: bool = False):
        self.inline_bytes = inline_bytes
        self.processes = processes
        self.blob_root = blob_root  # where the assets that scenes reference are read
        self.packet = packet  # the workers render with the packet kernel: ask if it covers scenes
        self._pool: ProcessPoolExecutor | None = None

    async def read(self, body: bytes, content_type: str | None) -> Submission | Rejection:
        limits = Limits()  # read here: the environment of the service, not of a child
        if len(body) <= self.inline_bytes:
            return await run_in_threadpool(read_submission, body, content_type, limits,
                                           self.blob_root, self.packet)
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.processes,
                                             mp_context=multiprocessing.get_context("spawn"))
        pool = self._pool
        try:
            # Submitted from a thread: the first submission spawns the process
            future = await run_in_threadpool(pool.submit, read_submission, body, content_type,
                                             limits, self.blob_root, self.packet)
            return await asyncio.wrap_future(future)
        except BrokenProcessPool:
            # The process died (killed for memory?): the next large body starts a new one.
            if self._pool is pool:
                self._pool = None
            pool.shutdown(wait=False, cancel_futures=True)
            return Rejection(status.HTTP_503_SERVICE_UNAVAILABLE, {
                "detail": "the process reading the submission died (out of memory?); try again"})

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
