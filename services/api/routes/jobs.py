"""``/api/jobs``: submit, list, inspect, fetch the image, cancel and retry jobs."""

from __future__ import annotations

import time
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from services.api.deps import ArchiveDep, CeleryDep, SettingsDep, StoreDep, SubmitterDep
from services.api.guards import echo_text, error_content
from services.api.intake import Rejection
from services.api.models import JobCreate, JobDetail, JobPublic, JobsPublic, JobStatus, TilePublic
from services.farm.archive import Archive
from services.farm.images import MEDIA, encode
from services.farm.jobs import Refusal, queue_job
from services.farm.jobs import retry_job as retry
from services.farm.merge import assemble
from services.farm.store import ACTIVE, FINAL, JobMeta, is_job_id

router = APIRouter(prefix="/jobs", tags=["jobs"])


def to_public(meta: JobMeta) -> JobPublic:
    plan = meta.plan
    end = meta.finished_at or time.time()
    rate = None
    if meta.started_at and meta.samples_merged:
        rate = meta.samples_merged / max(end - meta.started_at, 1e-6)
    eta = None
    if meta.status in ACTIVE and rate:
        eta = (meta.samples_planned - meta.samples_merged) / rate
    elif meta.status == "done":
        eta = 0.0
    return JobPublic(
        id=meta.id, name=meta.name, status=meta.status, priority=meta.priority,  # type: ignore[arg-type]
        width=plan.width, height=plan.height, spp=plan.spp, tile_size=plan.tile_size,
        spp_per_pass=plan.spp_per_pass,
        max_spp_per_pass=plan.pass_cap, passes=plan.n_passes,
        largest_pass=max(count for _, count in plan.passes),
        tiles=plan.n_tiles, tasks_total=plan.n_tasks,
        tasks_merged=meta.tasks_merged, samples_planned=meta.samples_planned,
        samples_merged=meta.samples_merged,
        progress=meta.samples_merged / meta.samples_planned if meta.samples_planned else 1.0,
        samples_per_second=rate, eta_seconds=eta, dropped_samples=meta.dropped,
        created_at=meta.created_at, started_at=meta.started_at, finished_at=meta.finished_at,
        error=meta.error, image_version=meta.version, methods=meta.methods,
        submitter=meta.submitter,
    )


def valid_job_id(job_id: Annotated[str, Path(description="the id POST /api/jobs answered "
                                                       "(32 hexadecimal digits)")]) -> str:
    """The path's job id, or 404 when it has not the form of one: checked before the id becomes
    part of a Redis key, where ``<id>:scene`` would name another of the job's keys."""
    if not is_job_id(job_id):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            detail=f"no job {echo_text(job_id, 64)!r}: not a job id "
                                   "(32 hexadecimal digits)")
    return job_id


JobId = Annotated[str, Depends(valid_job_id)]


def _get_or_404(archive: Archive, job_id: str) -> JobMeta:
    """The job, live from Redis while it is there, else from its record."""
    found = archive.job(job_id)
    if found is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
    return found[0]


# The body is read by the route (services/api/intake.py), not by FastAPI; the schema says what
# it holds all the same (the OpenAPI document, the fuzzing).
_JOB_CREATE_BODY = {"requestBody": {"required": True, "content": {
    "application/json": {"schema": JobCreate.model_json_schema()}}}}


@router.post("", status_code=status.HTTP_201_CREATED, response_model=JobPublic,
             openapi_extra=_JOB_CREATE_BODY, responses={
                 400: {"description": "a body the JSON parser gives up on"},
                 422: {"description": "an invalid request or an invalid or over-limit scene; "
                                      "`loc` names the field"},
                 429: {"description": "the farm's backlog is full (LUCENT_MAX_QUEUED_SAMPLES)"}})
async def create_job(request: Request, store: StoreDep, celery: CeleryDep,
                     settings: SettingsDep, archive: ArchiveDep, submitter: SubmitterDep):
    """Validate the request and its scene (``JobCreate``), plan tiles × passes and queue them.
    Nothing is queued if the scene is invalid or over a limit."""
    read = await request.app.state.intake.read(await request.body(),
                                               request.headers.get("content-type"))
    if isinstance(read, Rejection):
        return JSONResponse(status_code=read.status, content=read.content)
    answer = await run_in_threadpool(queue_job, store, celery, settings, read.options, read.scene,
                                     archive.records, submitter)
    if isinstance(answer, Refusal):
        return JSONResponse(status_code=answer.status, headers=answer.headers,
                            content=error_content({"loc": loc, "msg": msg, "type": kind}
                                                  for loc, msg, kind in answer.errors))
    return to_public(answer)


# Past any job list a farm keeps, and within what every database takes for OFFSET.
MAX_OFFSET = 10**9


@router.get("", response_model=JobsPublic)
def list_jobs(archive: ArchiveDep,
              status_: Annotated[JobStatus | None, Query(alias="status")] = None,
              offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
              limit: Annotated[int, Query(ge=1, le=500)] = 50):
    """Newest first, from the job database (paged and filtered there); the jobs in flight show
    their live progress."""
    metas, total = archive.page(status_, offset, limit)
    return JobsPublic(data=[to_public(m) for m in metas], count=total, offset=offset, limit=limit)


@router.get("/{job_id}", response_model=JobDetail)
def get_job(job_id: JobId, archive: ArchiveDep):
    """Status, progress, per-tile state and samples: answered from Redis while the job is in
    flight, from its record once it is archived; no image touched."""
    found = archive.job(job_id)
    if found is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
    meta, table = found
    states, samples, errors = table.states, table.samples, table.errors
    tiles = []
    for t in range(meta.plan.n_tiles):
        x0, y0, w, h = meta.plan.tile_rect(t)
        tiles.append(TilePublic(index=t, x0=x0, y0=y0, width=w, height=h,
                                state=states.get(t, "queued"), samples=samples.get(t, 0),
                                error=errors.get(t)))
    tile_errors = [f"tile {t}: {e}" for t, e in sorted(errors.items())]
    # A failed tile fails its job with the same words: say it once.
    all_errors = ([meta.error] if meta.error and meta.error not in tile_errors else []) + \
        tile_errors
    return JobDetail(**to_public(meta).model_dump(), tile_states=tiles, errors=all_errors)


# Stops: the preview is scaled by 2**exposure in float32 (to_srgb8). A finite number in a range
# that float32 holds with room to spare (2**64 ~ 1.8e19; the dashboard's slider spans +-5).
MAX_EXPOSURE = 64.0
Exposure = Annotated[float, Query(ge=-MAX_EXPOSURE, le=MAX_EXPOSURE, allow_inf_nan=False,
                                  description="stops, PNG only: the image times 2**exposure")]


@router.get("/{job_id}/image.{fmt}", responses={
    200: {"content": {m: {} for m in MEDIA.values()}}, 304: {"description": "not modified"},
    410: {"description": "a finished job whose image is no longer stored"}})
def get_image(job_id: JobId, fmt: Literal["png", "exr", "npy"], request: Request,
              store: StoreDep, archive: ArchiveDep, exposure: Exposure = 0.0,
              tonemap: Literal["clamp", "reinhard", "aces"] = "clamp"):
    """The merged image as it stands (progressive while running; from the blob store once the
    job is archived). ``ETag`` changes with every merge; send it back in ``If-None-Match`` to get
    304 when nothing changed."""
    meta = store.get_job(job_id)
    record = archive.records.get(job_id) if meta is None else None
    if record is not None:
        meta = record.meta
    if meta is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
    etag = f'"{job_id}-{meta.version}-{fmt}-{exposure:g}-{tonemap}"'
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    if record is not None:
        data = archive.stored_image(record, fmt, exposure, tonemap)
        if isinstance(data, str):
            raise HTTPException(status.HTTP_410_GONE, detail=data)
        return Response(content=data, media_type=MEDIA[fmt], headers=headers)
    # The buffers are read after the version: the image is never older than its ETag says.
    assembled = assemble(store, job_id)
    if assembled is None:  # archived meanwhile: the stored image is the same
        return get_image(job_id, fmt, request, store, archive, exposure, tonemap)
    image = assembled[0].mean()
    return Response(content=encode(image, fmt, exposure, tonemap), media_type=MEDIA[fmt],
                    headers=headers)


@router.delete("/{job_id}", response_model=JobPublic, responses={
    204: {"description": "a finished job, deleted: its record, image and scene"}})
def delete_job(job_id: JobId, store: StoreDep, archive: ArchiveDep):
    """A queued or running job is cancelled (queued tasks do nothing when they come up; running
    ones finish their pass) and answered; a finished one is deleted (204)."""
    meta = _get_or_404(archive, job_id)
    if meta.status in FINAL:
        archive.remove(job_id)
        return Response(status_code=status.HTTP_204_NO_CONTENT)
    store.cancel_job(job_id)
    return to_public(_get_or_404(archive, job_id))


@router.post("/{job_id}/retry", response_model=JobPublic)
def retry_job(job_id: JobId, store: StoreDep, celery: CeleryDep, archive: ArchiveDep):
    """Requeue every pass not merged yet of a failed or cancelled job (tries counted afresh)."""
    refused = retry(store, celery, archive, _get_or_404(archive, job_id))
    if refused is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, detail=refused)
    return to_public(_get_or_404(archive, job_id))
