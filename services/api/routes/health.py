"""``/healthz`` (the process is up), ``/readyz`` (Redis and the job database answer),
``/metrics`` (Prometheus).

The probes are open; ``/metrics`` tells how busy the farm is and sits behind the API token when
one is set (Prometheus sends it with ``authorization: {credentials_file: ...}``)."""

from __future__ import annotations

from collections import Counter

import redis
from fastapi import APIRouter, Response, status
from fastapi.responses import PlainTextResponse

from services.api.deps import ArchiveDep, StoreDep
from services.farm.records import RecordsUnavailable
from services.farm.store import STATUSES

router = APIRouter(tags=["health"])
metrics_router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz")
def readyz(store: StoreDep, archive: ArchiveDep, response: Response) -> dict[str, str]:
    try:
        store.ping()
    except redis.RedisError as err:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
        return {"status": "unavailable", "redis": str(err)}
    try:
        archive.records.ping()
    except RecordsUnavailable as err:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
        return {"status": "unavailable", "database": str(err)}
    return {"status": "ok"}


@metrics_router.get("/metrics", response_class=PlainTextResponse)
def metrics(store: StoreDep, archive: ArchiveDep) -> str:
    """Prometheus text format (version 0.0.4)."""
    by_status = archive.records.count_by_status()
    workers = store.workers()
    live = Counter(w.get("state", "lost") for w in workers)
    counters = store.metrics()
    lines = [
        "# HELP lucent_jobs Jobs by status.",
        "# TYPE lucent_jobs gauge",
        *(f'lucent_jobs{{status="{s}"}} {by_status.get(s, 0)}' for s in STATUSES),
        "# HELP lucent_workers Worker processes by state.",
        "# TYPE lucent_workers gauge",
        *(f'lucent_workers{{state="{s}"}} {n}' for s, n in sorted(live.items())),
        "# HELP lucent_tasks_done_total Passes rendered.",
        "# TYPE lucent_tasks_done_total counter",
        f"lucent_tasks_done_total {counters.get('tasks_done', 0):g}",
        "# HELP lucent_paths_total Camera paths traced.",
        "# TYPE lucent_paths_total counter",
        f"lucent_paths_total {counters.get('paths', 0):g}",
        "# HELP lucent_render_seconds_total Seconds spent in render_tile.",
        "# TYPE lucent_render_seconds_total counter",
        f"lucent_render_seconds_total {counters.get('render_seconds', 0):g}",
        "# HELP lucent_pending_passes Pass buffers written and not merged yet.",
        "# TYPE lucent_pending_passes gauge",
        f"lucent_pending_passes {store.pending_count()}",
    ]
    return "\n".join(lines) + "\n"
