"""``/healthz`` (the process is up), ``/readyz`` (Redis and the job database answer, a worker is
alive),
``/metrics`` (Prometheus).

The probes are open, so they say what is wrong in general words only (no host, port or farm
data: ``services.farm.availability``); ``/metrics`` tells how busy the farm is and sits behind
the API token when one is set (Prometheus sends it with ``authorization: {credentials_file:
...}``)."""

from __future__ import annotations

import logging
from collections import Counter

from fastapi import APIRouter, Response, status
from fastapi.responses import PlainTextResponse

from services.api.deps import RecordsDep, StoreDep
from services.farm.availability import readiness
from services.farm.pools import live, worker_protocol
from services.farm.records import RecordsUnavailable
from services.farm.store import STATUSES

log = logging.getLogger(__name__)

router = APIRouter(tags=["health"])
metrics_router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "Redis does not answer, or no worker "
                                                     "process is alive; `reasons` says which"}})
def readyz(store: StoreDep, records: RecordsDep,
           response: Response) -> dict[str, str | list[str]]:
    reasons = readiness(store)
    try:
        records.ping()
    except RecordsUnavailable as err:
        log.warning("%s", err)
        reasons.append("the job database does not answer")
    if reasons:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
        return {"status": "unavailable", "reasons": reasons}
    return {"status": "ok"}


def _label(value: str) -> str:
    """A Prometheus label value, escaped (a heartbeat's text)."""
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


@metrics_router.get("/metrics", response_class=PlainTextResponse)
def metrics(store: StoreDep, records: RecordsDep) -> str:
    """Prometheus text format (version 0.0.4)."""
    records.sync(store.jobs_in_flight())
    by_status = records.count_by_status()
    workers = store.workers()
    by_state = Counter(w.get("state", "lost") for w in workers)
    # (a farm upgraded worker by worker: its live workers by release, kernel and merge protocol)
    releases = Counter((w.get("version") or "", w.get("kernel") or "", worker_protocol(w) or 1)
                       for w in live(workers))
    counters = store.metrics()
    lines = [
        "# HELP lucent_jobs Jobs by status.",
        "# TYPE lucent_jobs gauge",
        *(f'lucent_jobs{{status="{s}"}} {by_status.get(s, 0)}' for s in STATUSES),
        "# HELP lucent_workers Worker processes by state.",
        "# TYPE lucent_workers gauge",
        *(f'lucent_workers{{state="{_label(s)}"}} {n}' for s, n in sorted(by_state.items())),
        "# HELP lucent_worker_releases Live worker processes by release, kernel and merge "
        "protocol (empty: a worker from before its heartbeat said).",
        "# TYPE lucent_worker_releases gauge",
        *(f'lucent_worker_releases{{version="{_label(v)}",kernel="{_label(k)}",'
          f'protocol="{p}"}} {n}' for (v, k, p), n in sorted(releases.items())),
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
