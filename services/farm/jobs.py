"""Submitting a job: the farm's policy between a validated request and the queue, in two steps.

``check_scene`` is pure CPU work, no store: the scene through ``renderer.scene.load_scene`` with
the farm's limits (mesh paths are refused), what ``auto`` picks for each material, and the scene's
JSON as it is stored. The API runs it off its event loop (``services/api/intake.py``: a process
of its own for large bodies).

``queue_job`` takes a checked scene: chooses the passes (the first pass as asked or the default,
never more than the scene's spp; the largest pass as asked, else the default but never below the
first), plans tiles × passes, refuses a plan over the task limit or the cost limits
(``services.farm.cost``), writes the job's record (``services.farm.records``), creates the job in
the store and queues its passes. A submission with an ``Idempotency-Key`` that a job's record
holds already is that job (``Replayed``), not a new one: a client that sends a submission again
(its answer lost, a 503, a timeout) gets one job.

The route (``services/api/routes/jobs.py``) only turns a ``Refusal`` into its HTTP answer.
"""

from __future__ import annotations

import contextlib
import json
import re
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

from celery import Celery

from renderer.materials.auto import auto_choices, describe_choice, frame_bias
from renderer.scene import Limits, SceneError, load_scene
from services.farm.blobs import asset_reader, open_blob_store
from services.farm.cost import check_cost
from services.farm.frames import PatchError, apply_patch
from services.farm.planner import Plan, chain_heads, default_tile_size
from services.farm.pools import (
    eligible,
    live_tag_sets,
    merge_protocol,
    packet_workers,
    waiting_for,
)
from services.farm.queue import enqueue
from services.farm.records import Records, RecordsUnavailable, Submission
from services.farm.settings import Settings
from services.farm.store import FRAME_SUMS_PROTOCOL, MERGE_PROTOCOL, JobMeta, JobStore

Loc = list[str | int]

_PATH_TOKEN = re.compile(r'\.?([A-Za-z_][A-Za-z0-9_\-]*)|\[(\d+)\]|\[("(?:[^"\\]|\\.)*")\]')


def scene_loc(path: str) -> Loc:
    """``objects[3].radius`` -> ``["body", "scene", "objects", 3, "radius"]``."""
    loc: Loc = ["body", "scene"]
    for name, index, quoted in _PATH_TOKEN.findall(path):
        loc.append(name if name else int(index) if index else json.loads(quoted))
    return loc


@dataclass(frozen=True)
class Refusal:
    """Why a submission was not queued: the HTTP status (422: fix the request; 429: the farm's
    backlog is full, try later), and each error as (loc in the request body, message, type)."""

    status: int
    errors: list[tuple[Loc, str, str]]
    headers: dict[str, str] | None = field(default=None)


@dataclass(frozen=True)
class Replayed:
    """A submission sent again: its ``Idempotency-Key`` found the job the first one made (the
    job as it is now); nothing new is queued."""

    meta: JobMeta


def _replayed(store: JobStore, prior: JobMeta, digest: str | None,
              submission: Submission) -> Replayed | Refusal:
    """The answer to a submission whose key ``prior``'s record holds: that job, if the body is
    the same; else a 422 on the key (one key, one request)."""
    if digest != submission.digest:
        return Refusal(422, [(["header", "Idempotency-Key"],
                              f"this key was sent before with another request (job {prior.id}): "
                              "a new request needs a new key", "value_error")])
    return Replayed(store.get_job(prior.id) or prior)


@dataclass(frozen=True)
class JobOptions:
    """How a client asks for its scene to be rendered, as the API validated it (``JobCreate``
    less the scene)."""

    name: str = ""
    priority: int = 0
    tile_size: int | None = None
    spp_per_pass: int | None = None
    max_spp_per_pass: int | None = None
    tags: tuple[str, ...] = ()  # worker tags the job requires (services.farm.pools)
    check_workers: bool = False  # refuse (409) when no live worker has the tags
    denoise: bool = False  # the done image denoised (services.farm.archive.frame_exr)


@dataclass(frozen=True)
class CheckedScene:
    """A scene that ``load_scene`` accepted, reduced to what planning and queueing need."""

    width: int
    height: int
    spp: int
    methods: dict[str, str]  # what ``auto`` picks for each material, and why
    scene_json: bytes  # the scene as submitted, as the store keeps it (workers re-fetch it)
    frames_json: bytes | None = None  # a job of frames: their JSON Patches
    n_frames: int = 1
    target_error: float | None = None  # render.target_error (the frame's expected relMSE)
    # with a target: the bias auto's models may add to it, the largest over the frames
    # (renderer.materials.auto.frame_bias; the workers aim the samples' noise at the rest)
    expected_bias: float = 0.0
    packet: bool = False  # the packet kernel covers the scene (asked on packet farms only)


def packet_covers(scene) -> bool:
    """Whether the packet kernel renders this validated scene (``renderer.packet.unsupported``
    of the compiled scene is None). A scene with more objects or mesh triangles than the kernel
    takes primitives is not compiled to find out: it cannot be."""
    from renderer.geometry.flat import FLAT_MAX
    from renderer.packet import unsupported
    from renderer.scene.compile import compile_scene

    if len(scene.objects) > FLAT_MAX or sum(
            len(o.model_arrays()[1]) for o in scene.objects if o.type == "mesh") > FLAT_MAX:
        return False
    try:
        return unsupported(compile_scene(scene)) is None
    except ValueError:  # CompileError: the workers fail the job with the reason
        return False


def check_scene(scene: Any, limits: Limits, blob_root: str | None = None,
                frames: list | None = None, packet: bool = False) -> CheckedScene | Refusal:
    """Validate a scene document with ``limits`` (the farm's, read where the request came in).
    Its asset references (``{"asset": "sha256:…"}``) are read from the blob store in
    ``blob_root`` (a folder or ``s3://bucket/prefix``): an unknown one is refused by its field;
    without a blob store, every one is. With ``frames`` (JSON Patches), every frame's scene is
    validated the same way, and must keep the film size and spp: an error names the frame and
    the operation (``["body", "frames", 2, 0, "path"]``) or the frame's scene field
    (``["body", "frames", 2, "scene", "render", "spp"]``). ``packet``: the farm's workers render
    with the packet kernel, so ask whether it covers the scene (``packet_covers``, which compiles
    a small scene: not done for a farm of other kernels, whose passes do not depend on it)."""
    assets = asset_reader(open_blob_store(blob_root)) if blob_root is not None else None
    try:
        parsed = load_scene(scene, limits=limits, assets=assets)  # mesh paths are refused
    except SceneError as err:
        return Refusal(422, [(scene_loc(p), m, "scene") for p, m in err.errors])
    errors: list[tuple[Loc, str, str]] = []
    frame_scenes = []
    for i, patch in enumerate(frames or []):
        try:
            frame = apply_patch(scene, patch)
        except PatchError as err:
            loc: Loc = ["body", "frames", i]
            if err.index >= 0:
                loc.append(err.index)
            if err.field:
                loc.append(err.field)
            errors.append((loc, f"frame {i}: operation {err.index}: {err.message}", "patch"))
            continue
        try:
            fp = load_scene(frame, limits=limits, assets=assets)
        except SceneError as err:
            errors += [(["body", "frames", i, *scene_loc(p)[1:]], f"frame {i}: {m}", "scene")
                       for p, m in err.errors]
            continue
        frame_scenes.append(fp)
        if (fp.film.width, fp.film.height, fp.render.spp) != \
                (parsed.film.width, parsed.film.height, parsed.render.spp):
            errors.append((["body", "frames", i], f"frame {i}: a frame keeps the scene's film "
                           f"size and spp ({parsed.film.width}x{parsed.film.height}, "
                           f"{parsed.render.spp} spp)", "patch"))
    if errors:
        return Refusal(422, errors)
    # What `auto` picks for each material (the workers compile the same choice)
    choices = auto_choices(parsed)
    methods = {name: f"{c.method}: {describe_choice(c.reason, c.expected_error)}"
               for name, c in choices.items()}
    bias = 0.0
    if parsed.render.target_error is not None and choices:
        # (each frame's camera and objects may differ; cheap: no BVH)
        bias = max([frame_bias(parsed, choices), *(frame_bias(fp) for fp in frame_scenes)])
    return CheckedScene(parsed.film.width, parsed.film.height, parsed.render.spp, methods,
                        json.dumps(scene).encode(),
                        json.dumps(frames).encode() if frames else None,
                        len(frames) if frames else 1, parsed.render.target_error,
                        packet=packet and packet_covers(parsed), expected_bias=bias)


def queue_job(store: JobStore, records: Records, celery: Celery, settings: Settings,
              options: JobOptions, scene: CheckedScene, submitter: str | None = None,
              submission: Submission | None = None) -> JobMeta | Replayed | Refusal:
    """Plan and queue a job, or say why not; nothing is queued when the answer is a Refusal.
    ``submission``: the request's ``Idempotency-Key`` (``records.request_key``) and body digest;
    a job whose record holds that key is the answer (``Replayed``), before any limit."""
    if submission is not None and (prior := records.by_request(submission.key)) is not None:
        return _replayed(store, *prior, submission)
    # The default passes of a scene the workers' packet kernel covers (asked by check_scene on
    # a farm of packet workers) are as many times larger as that kernel is faster: a task as
    # long, its fixed cost as small a share; where no live worker renders with it (scalar nodes
    # behind a service left at the default), the scalar kernel's
    # (the heartbeats of the live workers that take the job, read where they decide something:
    # here and for the frames' sums)
    workers = (eligible(store.workers(), options.tags)
               if scene.packet or (scene.target_error is not None and scene.n_frames > 1)
               else [])
    packet = scene.packet and packet_workers(workers, True)
    first = min(options.spp_per_pass or (settings.packet_spp_per_pass if packet
                                         else settings.default_spp_per_pass), scene.spp)
    # The largest pass: as asked, else the default but never below the first pass
    largest = options.max_spp_per_pass or max(first, settings.packet_max_spp_per_pass if packet
                                              else settings.default_max_spp_per_pass)
    if largest < first:
        return Refusal(422, [(["body", "max_spp_per_pass"],
                              f"the largest pass ({largest}) is smaller than the first "
                              f"(spp_per_pass {first})", "value_error")])
    tile = options.tile_size or default_tile_size(scene.width, scene.height,
                                                  settings.default_tile_size)
    # A job with a target error: passes that double the samples so far (its chain stops a tile
    # at the first pass that finds it converged; larger steps would overshoot the target)
    growth = settings.pass_growth if scene.target_error is None else 1
    plan = Plan(scene.width, scene.height, scene.spp, tile, first, largest, scene.n_frames,
                growth)
    if plan.n_tasks > settings.max_tasks_per_job:
        msg = (f"{plan.n_tiles} tiles{f' ({plan.frames} frames)' if plan.frames > 1 else ''} x "
               f"{plan.n_passes} passes = {plan.n_tasks} tasks exceed the "
               f"limit {settings.max_tasks_per_job} (LUCENT_MAX_TASKS_PER_JOB): use larger tiles "
               "or passes")
        return Refusal(422, [(["body", "tile_size"], msg, "limit"),
                             (["body", "spp_per_pass"], msg, "limit"),
                             (["body", "max_spp_per_pass"], msg, "limit")])
    refused = check_cost(plan, store, settings)
    if refused is not None:
        # 429 (a full backlog) clears by itself as jobs finish; 422 needs a smaller job.
        return Refusal(refused.status,
                       [(list(loc), refused.msg, "limit") for loc in refused.locs],
                       {"Retry-After": "60"} if refused.status == 429 else None)
    if options.denoise:
        from renderer.film.denoise import MISSING, oidn_available

        if not oidn_available():
            return Refusal(422, [(["body", "denoise"], f"this farm cannot denoise: {MISSING}",
                                  "value_error")])
    if options.check_workers:
        waiting = waiting_for(options.tags, live_tag_sets(store.workers()))
        if waiting is not None:
            return Refusal(409, [(["body", "tags"], f"no live worker has the tags "
                                  f"{','.join(options.tags)} (LUCENT_WORKER_TAGS); without "
                                  "check_workers the job would wait for one", "workers")])
    job_id = uuid.uuid4().hex  # store.JOB_ID's form
    # The record first: with the database away, nothing is queued (503) and the job is not run
    # unrecorded; with Redis away after it, the record goes again (the sweeper would fail it).
    created = JobMeta.new(job_id, options.name, options.priority, plan, scene.methods,
                          time.time(), submitter, options.tags, options.denoise,
                          scene.target_error, scene.expected_bias)
    prior = records.create(created, submission)
    if prior is not None and submission is not None:
        return _replayed(store, *prior, submission)  # the same request at the same moment
    # A target job of frames keeps each frame's sums where the merge of every live worker that
    # takes it does (a farm upgraded worker by worker: else its frames' sums pool, as an old
    # worker's merge keeps)
    frame_sums = (plan.frames == 1 or scene.target_error is None
                  or merge_protocol(workers, MERGE_PROTOCOL) >= FRAME_SUMS_PROTOCOL)
    try:
        meta = store.create_job(job_id, options.name, options.priority, plan, scene.scene_json,
                                scene.methods, created.created_at, submitter, options.tags,
                                scene.frames_json, scene.target_error, options.denoise,
                                scene.expected_bias, frame_sums)
    except Exception:
        with contextlib.suppress(RecordsUnavailable):
            records.delete(job_id)
        raise
    # A job with a target error queues each tile's first pass; each pass queues the next
    order = plan.order() if scene.target_error is None else chain_heads(plan.order())
    enqueue(celery, job_id, order, options.priority, options.tags)
    return meta


def retry_job(store: JobStore, celery: Celery, meta: JobMeta) -> str | None:
    """Queue again every pass not merged yet of a failed or cancelled job, its tries counted
    afresh; None when done, else why the job cannot be retried."""
    if meta.status not in ("failed", "cancelled"):
        return f"job {meta.id} is {meta.status}: only failed or cancelled jobs can be retried"
    todo = store.reopen_job(meta.id)
    if meta.target_error is not None:
        todo = chain_heads(todo)  # the rest follow one after the other, as when it was queued
    enqueue(celery, meta.id, todo, meta.priority, meta.tags)
    store.finish_if_complete(meta.id)  # nothing was left to render
    return None
