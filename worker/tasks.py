"""The one task: render one pass of one tile of a job, store it, merge it.

``render_pass(job_id, tile, pass_index)`` is thin and idempotent: it takes ids, re-fetches the
scene from Redis (compiled once per process), renders the pass's sample range with
``renderer.render.render_tile``, writes the ``SampleBuffer`` under the deterministic key
``{prefix}:job:{id}:pass:{tile}:{pass}`` and merges it (``services.farm.merge.merge_pass``, exactly
once however often the task runs). Running it twice costs a render, never a double count.
"""

from __future__ import annotations

import logging
import time

import redis
from celery import signals
from celery.exceptions import Reject, SoftTimeLimitExceeded

from renderer.film.buffer import SampleBuffer
from services.farm.merge import merge_pass
from services.farm.planner import celery_priority
from services.farm.settings import get_settings
from services.farm.store import FINAL
from worker import runtime
from worker.celery_app import app

log = logging.getLogger(__name__)


@signals.worker_init.connect
def _init_worker(**_: object) -> None:
    """In the worker node's main process, before the pool forks: fill a cold kernel cache once."""
    if not get_settings().prewarm:
        return
    seconds = runtime.prewarm_cache()
    if seconds is not None:
        log.warning("kernel cache was cold: compiled in %.1f s before the pool started", seconds)


@signals.worker_process_init.connect
def _init_process(**_: object) -> None:
    """In each pool process, after the fork: fresh state, numba threads, JIT warm-up, heartbeat."""
    import numba

    runtime.STATE = state = runtime.WorkerState()
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    state.start_heartbeat()
    seconds = state.warm_up()
    state.set_task("")
    log.info("worker process %s warm in %.2f s", state.worker_id, seconds)


@signals.worker_process_shutdown.connect
def _shutdown_process(**_: object) -> None:
    runtime.STATE.stop_heartbeat()


# Redis unreachable (restarting, a network cut): nothing about the pass can be recorded.
REDIS_DOWN = (redis.ConnectionError, redis.TimeoutError)


@app.task(name="worker.tasks.render_pass", bind=True)
def render_pass(self, job_id: str, tile: int, pass_index: int) -> str:
    """Render, store and merge pass ``pass_index`` of tile ``tile`` of job ``job_id``.

    Returns what happened (``merged``, ``duplicate``, ``skipped: <status>``, ``failed``), for logs.
    """
    try:
        return _render_pass(job_id, tile, pass_index)
    except REDIS_DOWN as err:
        # Put the message back rather than let Celery acknowledge a failed task: acknowledged,
        # the pass would never run again and its job would never finish. If Redis is still down
        # the message stays unacknowledged, and comes back after the visibility timeout.
        raise Reject(f"Redis unreachable: {err}", requeue=True) from err


def _render_pass(job_id: str, tile: int, pass_index: int) -> str:
    t_task = time.perf_counter()
    state = runtime.STATE
    store = state.store
    settings = state.settings

    # Cancelled, failed, done or deleted: queued tasks of such a job do nothing.
    meta = store.get_job(job_id)
    if meta is None or meta.status in FINAL:
        return f"skipped: {meta.status if meta else 'no such job'}"
    # Not a pass of this job's plan (a message sent for another plan of the same id, by hand or
    # by an older service): nothing to render, and no reason to fail the job's tiles over it.
    if not (0 <= tile < meta.plan.n_tiles and 0 <= pass_index < meta.plan.n_passes):
        return "skipped: no such pass"
    # Delivered again after it was merged (a redelivery): nothing to do.
    if store.is_merged(job_id, tile, pass_index):
        return "duplicate"
    # Count every delivery, so that a pass that keeps killing its worker stops being retried. Only
    # deliveries that run are counted (one lost by the broker, then re-queued by the sweeper, is
    # not), and counting one marks the job alive for the sweeper's stall rule.
    attempt = store.add_attempt(job_id, tile, pass_index)
    if attempt > settings.max_attempts:
        store.fail_tile(job_id, tile, f"pass {pass_index} gave up after {attempt - 1} tries "
                        "(its worker was lost or timed out each time)")
        return "failed"

    if meta.status == "queued":  # the job's first pass (one round trip fewer for the others)
        store.mark_started(job_id)
    store.set_tile_running(job_id, tile)
    state.set_task(f"{job_id}/{tile}/{pass_index}")
    try:
        return _render_and_merge(state, meta, tile, pass_index, t_task)
    except REDIS_DOWN:
        raise  # not the pass's fault: no try is spent on recording it
    except Exception as err:  # every other failure is recorded on the tile
        reason = ("timed out" if isinstance(err, SoftTimeLimitExceeded)
                  else f"{type(err).__name__}: {err}")
        if attempt >= settings.max_attempts:
            store.fail_tile(job_id, tile, f"pass {pass_index}: {reason} "
                            f"(after {attempt} tries)")
            return "failed"
        store.note_tile_error(job_id, tile, f"pass {pass_index}, try {attempt}: {reason}")
        render_pass.apply_async((job_id, tile, pass_index), countdown=1.0,
                                priority=celery_priority(meta.priority))
        return "retrying"
    finally:
        state.set_task("")


def _tile_converged(store, job_id: str, tile: int, target_error: float) -> bool:
    from renderer.film.adaptive import tile_converged

    data = store.tile_buffer(job_id, tile)
    return data is not None and tile_converged(SampleBuffer.from_bytes(data), target_error)


def _render_and_merge(state: runtime.WorkerState, meta, tile: int, pass_index: int,
                      t_task: float) -> str:
    from renderer.render import render_tile
    from renderer.scene import SceneError
    from renderer.scene.compile import CompileError

    store = state.store
    job_id = meta.id
    compiled = state.cached(job_id)
    try:
        if compiled is None:
            scene_json = store.get_scene(job_id)
            if scene_json is None:
                return "skipped: no scene"
            compiled = state.compiled(job_id, scene_json)
    except (SceneError, CompileError) as err:
        # Not renderable, whichever tile asks: fail the job with the reason, keep the worker.
        store.fail_job(job_id, str(err))
        return "failed"

    x0, y0, w, h = meta.plan.tile_rect(tile)
    start, count = meta.plan.sample_range(pass_index)
    if compiled.target_error is not None and _tile_converged(store, job_id, tile,
                                                             compiled.target_error):
        # Adaptive sampling: the tile's merged buffer meets the scene's target (a pure rule of
        # that buffer, renderer.film.adaptive.tile_converged), so this pass adds no samples. It
        # is still stored and merged, empty, so the job's task count completes as planned.
        buf = SampleBuffer.empty(x0, y0, w, h)
        store.put_pass(job_id, tile, pass_index, buf.to_bytes(), ttl=state.settings.pass_ttl)
        merged = merge_pass(store, job_id, tile, pass_index)
        store.set_tile_state(job_id, tile, "done")
        return "converged" if merged else "duplicate"
    t0 = time.perf_counter()
    buf = render_tile(compiled, x0, y0, w, h, start, count)
    seconds = time.perf_counter() - t0
    state.count_pass(w * h * count, seconds)

    store.put_pass(job_id, tile, pass_index, buf.to_bytes(), ttl=state.settings.pass_ttl)
    merged = merge_pass(store, job_id, tile, pass_index)
    # task_seconds - render_seconds: the per-task overhead (Redis, buffers, merge, bookkeeping).
    store.count(tasks_done=1, render_seconds=seconds, paths=w * h * count,
                task_seconds=time.perf_counter() - t_task)
    return "merged" if merged else "duplicate"
