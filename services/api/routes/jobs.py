"""``/api/jobs``: submit, list, inspect, fetch the image, cancel or delete, and retry jobs."""

from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Annotated, Literal

from fastapi import (
    APIRouter,
    Depends,
    Header,
    HTTPException,
    Path,
    Query,
    Request,
    Response,
    status,
)
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from renderer.film.adaptive import noise_target
from services.api.deps import (
    BlobsDep,
    CeleryDep,
    RecordsDep,
    SettingsDep,
    StoreDep,
    SubmitterDep,
)
from services.api.guards import echo_text, error_content
from services.api.intake import Rejection
from services.api.models import (
    FramePublic,
    JobCreate,
    JobDetail,
    JobPublic,
    JobsPublic,
    JobStatus,
    TilePublic,
)
from services.farm.archive import (
    assemble_parked,
    delete_finished,
    encode_image,
    final_image,
    frame_exr,
    unpark_job,
)
from services.farm.jobs import Refusal, Replayed, queue_job
from services.farm.jobs import retry_job as retry
from services.farm.merge import assemble
from services.farm.planner import Plan
from services.farm.pools import live_tag_sets, waiting_for
from services.farm.records import Records, Submission, request_key
from services.farm.store import ACTIVE, JobMeta, JobStore, is_job_id

router = APIRouter(prefix="/jobs", tags=["jobs"])


def to_public(meta: JobMeta, live_tags: list[frozenset[str]] | None = None) -> JobPublic:
    """The job's public form; with ``live_tags`` (the tags of each live worker), an active job
    that no live worker can take says what it waits for."""
    plan = meta.plan
    end = meta.finished_at or time.time()
    rate = None
    if meta.started_at and meta.samples_merged:
        rate = meta.samples_merged / max(end - meta.started_at, 1e-6)
    eta = None
    progress = meta.samples_merged / meta.samples_planned if meta.samples_planned else 1.0
    # (a job's record keeps them in its tiles' summary once it leaves Redis)
    target = (meta.target_error if meta.target_error is not None
              else meta.tiles_final.get("target_error"))
    noise = (meta.expected_error if meta.expected_error is not None
             else meta.tiles_final.get("expected_error"))
    # (the bias auto's models may add, which the samples' noise comes on top of)
    bias = meta.expected_bias or float(meta.tiles_final.get("expected_bias") or 0.0)
    expected = None if noise is None else noise + bias
    if meta.status in ACTIVE and target is not None:
        # A job with a target error stops when its error is reached, not at render.spp: its
        # progress is how far the samples' noise has fallen toward its share of the target (it
        # falls as 1 / samples, so share / noise is the share of the samples it needs that it
        # has), 0 before every pixel has an estimate (a job of frames' detail: ``job_detail``)
        progress, eta = _target_progress([noise], noise_target(target, bias),
                                         meta.samples_merged, rate)
    elif meta.status in ACTIVE and rate:
        eta = (meta.samples_planned - meta.samples_merged) / rate
    elif meta.status == "done":
        eta = 0.0
        if target is not None:
            progress = 1.0  # reached, whatever share of render.spp it took
    return JobPublic(
        id=meta.id, name=meta.name, status=meta.status, priority=meta.priority,  # type: ignore[arg-type]
        width=plan.width, height=plan.height, spp=plan.spp, tile_size=plan.tile_size,
        spp_per_pass=plan.spp_per_pass,
        max_spp_per_pass=plan.pass_cap, passes=plan.n_passes, pass_growth=plan.pass_growth,
        largest_pass=max(count for _, count in plan.passes),
        tiles=plan.n_tiles, frames=plan.frames, tasks_total=plan.n_tasks,
        tasks_merged=meta.tasks_merged, samples_planned=meta.samples_planned,
        samples_merged=meta.samples_merged,
        progress=progress, samples_per_second=rate, eta_seconds=eta, dropped_samples=meta.dropped,
        created_at=meta.created_at, started_at=meta.started_at, finished_at=meta.finished_at,
        error=meta.error, image_version=meta.version, methods=meta.methods,
        submitter=meta.submitter, tags=list(meta.tags),
        # (a job's record keeps them in its tiles' summary once it leaves Redis)
        denoise=meta.denoise or bool(meta.tiles_final.get("denoise")),
        target_error=target, expected_error=expected, expected_bias=bias,
        waiting_for=(waiting_for(meta.tags, live_tags)
                     if live_tags is not None and meta.status in ACTIVE else None),
    )


async def valid_job_id(job_id: Annotated[str, Path(description="the id POST /api/jobs answered "
                                                       "(32 hexadecimal digits)")]) -> str:
    """The path's job id, or 404 when it has not the form of one: checked before the id becomes
    part of a Redis key, where ``<id>:scene`` would name another of the job's keys."""
    if not is_job_id(job_id):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            detail=f"no job {echo_text(job_id, 64)!r}: not a job id "
                                   "(32 hexadecimal digits)")
    return job_id


JobId = Annotated[str, Depends(valid_job_id)]


def _get_or_404(store: JobStore, records: Records, job_id: str) -> JobMeta:
    """The job as Redis holds it while in flight, else its record (archived, or failed or
    cancelled and Redis restarted)."""
    meta = store.get_job(job_id) or records.get(job_id)
    if meta is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
    return meta


# An Idempotency-Key: 1–255 visible ASCII characters (a UUID, say), chosen by the client
IDEMPOTENCY_KEY = r"^[\x21-\x7e]{1,255}$"

# The body is read by the route (services/api/intake.py), not by FastAPI; the schema says what
# it holds all the same (the OpenAPI document, the fuzzing).
_JOB_CREATE_BODY = {"requestBody": {"required": True, "content": {
    "application/json": {"schema": JobCreate.model_json_schema()}}}}


@router.post("", status_code=status.HTTP_201_CREATED, response_model=JobPublic,
             openapi_extra=_JOB_CREATE_BODY, responses={
                 400: {"description": "a body the JSON parser gives up on"},
                 422: {"description": "an invalid request or an invalid or over-limit scene; "
                                      "`loc` names the field"},
                 200: {"description": "the same request sent again with its Idempotency-Key: "
                                      "the job the first one made (header Idempotent-Replayed)",
                       "model": JobPublic},
                 429: {"description": "the farm's backlog is full (LUCENT_MAX_QUEUED_SAMPLES)"}})
async def create_job(request: Request, response: Response, store: StoreDep,
                     records: RecordsDep, celery: CeleryDep, settings: SettingsDep,
                     submitter: SubmitterDep,
                     idempotency_key: Annotated[str | None, Header(
                         alias="Idempotency-Key", pattern=IDEMPOTENCY_KEY,
                         description="any 1–255 visible ASCII characters the client chooses "
                                     "for this request: sent again with the same body, it "
                                     "answers the job the first one made (200) instead of "
                                     "making another")] = None):
    """Validate the request and its scene (``JobCreate``), plan tiles × passes and queue them.
    Nothing is queued if the scene is invalid or over a limit. With an ``Idempotency-Key`` that
    an earlier request of the same submitter used, the answer is that request's job."""
    body = await request.body()
    read = await request.app.state.intake.read(body, request.headers.get("content-type"))
    if isinstance(read, Rejection):
        return JSONResponse(status_code=read.status, content=read.content)
    submission = None if idempotency_key is None else Submission(
        request_key(submitter, idempotency_key), hashlib.sha256(body).hexdigest())
    answer = await run_in_threadpool(queue_job, store, records, celery, settings, read.options,
                                     read.scene, submitter, submission)
    if isinstance(answer, Replayed):
        response.status_code = status.HTTP_200_OK
        response.headers["Idempotent-Replayed"] = "true"
        return to_public(answer.meta)
    if isinstance(answer, Refusal):
        return JSONResponse(status_code=answer.status, headers=answer.headers,
                            content=error_content({"loc": loc, "msg": msg, "type": kind}
                                                  for loc, msg, kind in answer.errors))
    return to_public(answer)


@router.get("", response_model=JobsPublic)
def list_jobs(store: StoreDep, records: RecordsDep,
              status_: Annotated[JobStatus | None, Query(alias="status")] = None,
              offset: Annotated[int, Query(ge=0, le=2**62)] = 0,
              limit: Annotated[int, Query(ge=1, le=500)] = 50):
    """Jobs newest first, filtered by status, paged: read from the job records, on indexes.
    The records of the jobs in flight are brought up to date first (only those that changed
    are written), and a listed job Redis holds is shown as Redis has it (its progress now)."""
    records.sync(store.jobs_in_flight())
    metas, total = records.page(status_, offset, limit)
    live = store.get_jobs([m.id for m in metas])
    tagged = any(m.tags and m.status in ACTIVE for m in live.values())
    live_tags = live_tag_sets(store.workers()) if tagged else None
    listed = [(meta, to_public(meta, live_tags)) for meta in (live.get(m.id, m) for m in metas)]
    # (as their detail has it: each frame's progress, from their tiles' estimates read at once)
    own = [(meta, public) for meta, public in listed if _frames_on_their_own(meta, public)]
    estimates = store.tile_estimates_of([meta.id for meta, _ in own]) if own else {}
    for meta, public in own:
        _frames_target_progress(public, meta.plan, estimates[meta.id])
    return JobsPublic(data=[public for _, public in listed], count=total, offset=offset,
                      limit=limit)


def _frames_on_their_own(meta: JobMeta, public: JobPublic) -> bool:
    """Whether ``meta`` is an active target job of frames, whose frames are each sampled to the
    target on their own: its progress is theirs, not the pooled noise's of ``to_public``."""
    return public.target_error is not None and meta.status in ACTIVE and meta.plan.frames > 1


def _frames_target_progress(public: JobPublic, plan: Plan,
                            estimates: dict[int, float]) -> list[float | None]:
    """Set an active target job of frames' progress and ETA from each frame's expected error
    (from its tiles' ``estimates``, with ``public``'s bias); returns those errors."""
    bias = public.expected_bias
    errors = [_frame_error(plan, f, estimates, bias) for f in range(plan.frames)]
    if public.target_error is not None:
        public.progress, public.eta_seconds = _target_progress(
            [None if e is None else e - bias for e in errors],
            noise_target(public.target_error, bias), public.samples_merged,
            public.samples_per_second)
    return errors


def _target_progress(noises: list[float | None], share: float, merged: int,
                     rate: float | None) -> tuple[float, float | None]:
    """An active target job's progress and ETA from its samples' noise (each frame's, for a job
    of frames, each sampled to the target on its own): the samples each needs (its share of
    those merged, as if even, times noise / share where it is above; the noise falls as 1 /
    samples) added up, against those merged; 0 and no ETA until each has an estimate (a
    noiseless one needs none more)."""
    if share <= 0 or not noises or any(n is None for n in noises):
        return 0.0, None
    needs = sum(max(1.0, n / share) for n in noises if n is not None) / len(noises)
    return 1.0 / needs, (merged * (needs - 1.0) / rate if rate else None)


def _frame_error(plan: Plan, frame: int, estimates: dict[int, float], bias: float) -> float | None:
    """A frame's expected relMSE from its tiles' estimates (each the mean of its pixels' error
    terms), weighted by their pixels, plus ``bias``; None until every tile of it has one."""
    total = 0.0
    for t in plan.frame_tiles(frame):
        if t not in estimates:
            return None
        _, _, w, h = plan.tile_rect(t)
        total += estimates[t] * w * h
    return total / (plan.width * plan.height) + bias


def job_detail(meta: JobMeta, states: dict[int, str], samples: dict[int, int],
               errors: dict[int, str], blocklist: dict[str, int], estimates: dict[int, float],
               live_tags: list[frozenset[str]] | None = None) -> JobDetail:
    if meta.tiles_final:  # out of Redis: its tiles' summary is in its record
        final = meta.tiles_final
        blocklist = final.get("blocklist", {})
        states = ({int(t): s for t, s in final["states"].items()} if "states" in final
                  else dict.fromkeys(range(meta.plan.n_tiles), "done"))
        samples = dict(enumerate(final.get("samples", [])))
        errors = {int(t): e for t, e in final.get("errors", {}).items()}
        estimates = {int(t): e for t, e in final.get("estimates", {}).items()}
    plan = meta.plan
    tiles = []
    merged = [0] * plan.frames  # pixel-samples of each frame
    for t in range(plan.n_tiles):
        x0, y0, w, h = plan.tile_rect(t)
        tiles.append(TilePublic(index=t, frame=plan.frame_of(t), x0=x0, y0=y0, width=w,
                                height=h, state=states.get(t, "queued"),
                                samples=samples.get(t, 0), error=errors.get(t),
                                expected_error=estimates.get(t)))
        merged[plan.frame_of(t)] += w * h * min(samples.get(t, 0), plan.spp)
    per_frame = plan.width * plan.height * plan.spp
    public = to_public(meta, live_tags)
    if _frames_on_their_own(meta, public):
        frame_errors = _frames_target_progress(public, plan, estimates)
    else:
        frame_errors = [_frame_error(plan, f, estimates, public.expected_bias)
                        for f in range(plan.frames)]
    frames = [FramePublic(index=f, progress=n / per_frame if per_frame else 1.0,
                          expected_error=frame_errors[f])
              for f, n in enumerate(merged)]
    tile_errors = [f"tile {t}: {e}" for t, e in sorted(errors.items())]
    # A failed tile fails its job with the same words: say it once.
    all_errors = ([meta.error] if meta.error and meta.error not in tile_errors else []) + \
        tile_errors
    return JobDetail(**public.model_dump(), frame_progress=frames,
                     tile_states=tiles,
                     errors=all_errors, blocklist=blocklist)


@dataclass(frozen=True)
class StatusView:
    """A job's status answer, encoded, with what it was made from and its ETag."""

    state: tuple
    body: bytes
    etag: str


class StatusViews:
    """``GET /api/jobs/{id}`` is what every open dashboard page polls. Each answer reads the job
    in one round trip (``JobStore.job_view``); when what it read is what the last answer of that
    job was made from, that answer's bytes are served again instead of being rebuilt (the models,
    the tile list, the JSON), and a client that sends its ``ETag`` gets 304 without a body. A
    running job's answer is rebuilt every time: its samples per second and ETA depend on the
    clock. At most ``size`` jobs' answers are kept (least recently asked for dropped first)."""

    def __init__(self, store: JobStore, records: Records, size: int = 1024):
        self.store = store
        self.records = records
        self.size = size
        self._views: OrderedDict[str, StatusView] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, job_id: str) -> StatusView | None:
        read = self.store.job_view(job_id)
        if read is None:  # archived (or Redis lost it): the record has it
            record = self.records.get(job_id)
            if record is None:
                return None
            read = (record, {}, {}, {}, {}, {})
        # A job requiring tags that is waiting: the workers are part of what its answer says
        live_tags = (live_tag_sets(self.store.workers())
                     if read[0].tags and read[0].status in ACTIVE else None)
        state = (*read, live_tags)
        with self._lock:
            view = self._views.get(job_id)
            if view is not None and view.state == state:
                self._views.move_to_end(job_id)
                return view
        body = job_detail(*state).model_dump_json().encode()
        view = StatusView(state, body, f'"{hashlib.blake2b(body, digest_size=12).hexdigest()}"')
        if read[0].status != "running":
            with self._lock:
                self._views[job_id] = view
                self._views.move_to_end(job_id)
                while len(self._views) > self.size:
                    self._views.popitem(last=False)
        return view


def etag_matches(request: Request, etag: str) -> bool:
    return etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]


@router.get("/{job_id}", response_model=JobDetail, responses={
    304: {"description": "not modified: the answer whose ETag was sent still holds"}})
def get_job(job_id: JobId, request: Request):
    """Status, progress, per-tile state and samples: answered from Redis, no image touched.
    ``ETag`` changes whenever the answer does; send it back in ``If-None-Match`` to get 304."""
    view = request.app.state.status_views.get(job_id)
    if view is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
    headers = {"ETag": view.etag, "Cache-Control": "no-cache"}
    if etag_matches(request, view.etag):
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    return Response(content=view.body, media_type="application/json", headers=headers)


_MEDIA = {"png": "image/png", "exr": "image/x-exr", "npy": "application/octet-stream"}

# Stops: the preview is scaled by 2**exposure in float32 (to_srgb8). A finite number in a range
# that float32 holds with room to spare (2**64 ~ 1.8e19; the dashboard's slider spans +-5).
MAX_EXPOSURE = 64.0
Exposure = Annotated[float, Query(ge=-MAX_EXPOSURE, le=MAX_EXPOSURE, allow_inf_nan=False,
                                  description="stops, PNG only: the image times 2**exposure")]


@router.get("/{job_id}/image.{fmt}", responses={
    200: {"content": {m: {} for m in _MEDIA.values()}}, 304: {"description": "not modified"}})
def get_image(job_id: JobId, fmt: Literal["png", "exr", "npy"], request: Request,
              store: StoreDep, records: RecordsDep, blobs: BlobsDep, exposure: Exposure = 0.0,
              tonemap: Literal["clamp", "reinhard", "aces"] = "clamp"):
    """The merged image as it stands (progressive while running; a done job's from the blob
    store, the same bytes); a job of frames: its first frame. ``ETag`` changes with every merge;
    send it back in ``If-None-Match`` to get 304 when nothing changed."""
    return _image(job_id, 0, fmt, request, store, records, blobs, exposure, tonemap)


@router.get("/{job_id}/frames/{frame}/image.{fmt}", responses={
    200: {"content": {m: {} for m in _MEDIA.values()}}, 304: {"description": "not modified"}})
def get_frame_image(job_id: JobId, frame: Annotated[int, Path(ge=0, le=1_000_000)],
                    fmt: Literal["png", "exr", "npy"], request: Request, store: StoreDep,
                    records: RecordsDep, blobs: BlobsDep, exposure: Exposure = 0.0,
                    tonemap: Literal["clamp", "reinhard", "aces"] = "clamp"):
    """Frame ``frame``'s image (0-based) of a job of frames, as ``image.{fmt}`` serves the
    job's."""
    return _image(job_id, frame, fmt, request, store, records, blobs, exposure, tonemap)


def _image(job_id: str, frame: int, fmt: str, request: Request, store: JobStore,
           records: Records, blobs, exposure: float, tonemap: str) -> Response:
    meta = _get_or_404(store, records, job_id)
    if frame >= meta.plan.frames:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            detail=f"job {job_id!r} has {meta.plan.frames} frame(s): no frame "
                                   f"{frame}")
    if meta.image_removed:
        raise HTTPException(status.HTTP_410_GONE,
                            detail=f"the image of job {job_id!r} was removed to keep the stored "
                                   "images under LUCENT_MAX_IMAGE_BYTES")
    etag = f'"{job_id}-{frame}-{meta.version}-{fmt}-{exposure:g}-{tonemap}"'
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if etag_matches(request, etag):
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    content = final_image(blobs, meta, fmt, exposure, tonemap, frame)
    if content is None:
        if meta.images:  # the blob store lost it: say so rather than serve a black frame
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                detail=f"the image of job {job_id!r} is missing from the blob "
                                       "store")
        # The buffers are read after the version: the image is never older than its ETag says.
        assembled = assemble(store, job_id, frame)
        if assembled is None and not meta.parked and not meta.images:
            # Left Redis since its answer was read (archived or parked now): read its record
            meta = _get_or_404(store, records, job_id)
            content = final_image(blobs, meta, fmt, exposure, tonemap, frame)
            if content is not None:
                return Response(content=content, media_type=_MEDIA[fmt], headers=headers)
        if assembled is None and meta.parked:  # out of Redis: its tiles are in the blob store
            assembled = assemble_parked(blobs, meta, frame)
        if assembled is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id!r}")
        if meta.status == "done" and (fmt == "exr" or meta.denoise):
            # with the scene's film.aovs as layers; denoised, for a job with denoise
            image, exr = frame_exr(store, blobs, meta, frame, assembled[0])
            content = exr if fmt == "exr" else encode_image(image, fmt, exposure, tonemap)
        else:
            content = encode_image(assembled[0].mean(), fmt, exposure, tonemap)
    return Response(content=content, media_type=_MEDIA[fmt], headers=headers)


@router.delete("/{job_id}", response_model=JobPublic, responses={
    204: {"description": "the job was finished (done, failed or cancelled): it is deleted, its "
                         "image too"}})
def cancel_job(job_id: JobId, store: StoreDep, records: RecordsDep, blobs: BlobsDep):
    """Cancel a queued or running job (200 and the job): queued tasks do nothing when they come
    up, running ones finish their pass. Delete a finished one (204): every key of it and its
    image; it is gone from the list."""
    meta = _get_or_404(store, records, job_id)
    if meta.status not in ACTIVE and delete_finished(store, records, blobs, job_id):
        return Response(status_code=status.HTTP_204_NO_CONTENT)
    store.cancel_job(job_id)
    return to_public(_get_or_404(store, records, job_id))


@router.post("/{job_id}/retry", response_model=JobPublic)
def retry_job(job_id: JobId, store: StoreDep, records: RecordsDep, blobs: BlobsDep,
              celery: CeleryDep):
    """Requeue every pass not merged yet of a failed or cancelled job (tries counted afresh)."""
    meta = _get_or_404(store, records, job_id)
    if store.get_status(job_id) is None and unpark_job(store, records, blobs, meta):
        meta = _get_or_404(store, records, job_id)  # back in Redis, as it was parked
    if store.get_status(job_id) is None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            detail=f"job {job_id} is {meta.status} and its passes are no longer "
                                   "in Redis: submit it again")
    refused = retry(store, celery, meta)
    if refused is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, detail=refused)
    return to_public(_get_or_404(store, records, job_id))
