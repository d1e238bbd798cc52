"""Submitting a job: the farm's policy between a validated request and the queue.

``submit_job`` checks the scene (``renderer.scene.load_scene`` with the farm's limits; mesh paths
are refused), chooses the passes (the first pass as asked or the default, never more than the
scene's spp; the largest pass as asked, else the default but never below the first), plans tiles
× passes, refuses a plan over the task limit or the cost limits (``services.farm.cost``), records
what ``auto`` picks for each material, creates the job in the store and queues its passes. The
route (``services/api/routes/jobs.py``) only turns a ``Refusal`` into its HTTP answer.
"""

from __future__ import annotations

import json
import re
import uuid
from dataclasses import dataclass, field
from typing import Any

from celery import Celery

from renderer.materials.auto import auto_choices
from renderer.scene import Limits, SceneError, load_scene
from services.farm.cost import check_cost
from services.farm.planner import Plan
from services.farm.queue import enqueue
from services.farm.settings import Settings
from services.farm.store import JobMeta, JobStore

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
class JobRequest:
    """What a client asks for, as the API validated it (``JobCreate``)."""

    scene: dict[str, Any]
    name: str = ""
    priority: int = 0
    tile_size: int | None = None
    spp_per_pass: int | None = None
    max_spp_per_pass: int | None = None


def submit_job(store: JobStore, celery: Celery, settings: Settings,
               request: JobRequest) -> JobMeta | Refusal:
    """Plan and queue a job, or say why not; nothing is queued when the answer is a Refusal."""
    try:
        scene = load_scene(request.scene, limits=Limits())  # mesh paths are refused
    except SceneError as err:
        return Refusal(422, [(scene_loc(p), m, "scene") for p, m in err.errors])
    first = min(request.spp_per_pass or settings.default_spp_per_pass, scene.render.spp)
    # The largest pass: as asked, else the default but never below the first pass
    largest = request.max_spp_per_pass or max(first, settings.default_max_spp_per_pass)
    if largest < first:
        return Refusal(422, [(["body", "max_spp_per_pass"],
                              f"the largest pass ({largest}) is smaller than the first "
                              f"(spp_per_pass {first})", "value_error")])
    plan = Plan(scene.film.width, scene.film.height, scene.render.spp,
                request.tile_size or settings.default_tile_size, first, largest)
    if plan.n_tasks > settings.max_tasks_per_job:
        msg = (f"{plan.n_tiles} tiles x {plan.n_passes} passes = {plan.n_tasks} tasks exceed the "
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
    job_id = uuid.uuid4().hex  # store.JOB_ID's form
    # What `auto` picks for each material (the workers compile the same choice)
    methods = {name: f"{c.method}: {c.reason}, expected relMSE {c.expected_error:.3g}"
               for name, c in auto_choices(scene).items()}
    meta = store.create_job(job_id, request.name, request.priority, plan,
                            json.dumps(request.scene), methods)
    enqueue(celery, job_id, plan.order(), request.priority)
    return meta


def retry_job(store: JobStore, celery: Celery, meta: JobMeta) -> str | None:
    """Queue again every pass not merged yet of a failed or cancelled job, its tries counted
    afresh; None when done, else why the job cannot be retried."""
    if meta.status not in ("failed", "cancelled"):
        return f"job {meta.id} is {meta.status}: only failed or cancelled jobs can be retried"
    todo = store.reopen_job(meta.id)
    enqueue(celery, meta.id, todo, meta.priority)
    store.finish_if_complete(meta.id)  # nothing was left to render
    return None
