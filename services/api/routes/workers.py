"""``/api/workers``: the farm's workers, from their heartbeats in Redis."""

from __future__ import annotations

import time

from fastapi import APIRouter

from services.api.deps import SettingsDep, StoreDep
from services.api.models import WorkerPublic, WorkersPublic
from services.farm.pools import worker_protocol

router = APIRouter(prefix="/workers", tags=["workers"])


@router.get("", response_model=WorkersPublic)
def list_workers(store: StoreDep, settings: SettingsDep):
    """Each worker process: host, state (``idle``, ``busy``, ``starting``; ``lost`` once its
    heartbeat has expired), current task, passes done, paths/s, last heartbeat, its node and the
    node's tags, its Lucent release, kernel and merge protocol."""
    out = []
    for w in store.workers():
        out.append(WorkerPublic(
            id=w["id"], host=w.get("host"), pid=int(w["pid"]) if w.get("pid") else None,
            state=w.get("state", "lost"), current_task=w.get("current_task") or None,
            tiles_done=int(w.get("tiles_done", 0)),
            paths_per_second=float(w.get("paths_per_second", 0.0)),
            last_heartbeat=float(w["last_heartbeat"]) if w.get("last_heartbeat") else None,
            node=w.get("node") or None, tags=[t for t in w.get("tags", "").split(",") if t],
            version=w.get("version") or None, kernel=w.get("kernel") or None,
            protocol=worker_protocol(w),
        ))
    return WorkersPublic(data=out, count=len(out), server_time=time.time(),
                         heartbeat_interval=settings.heartbeat_interval)
