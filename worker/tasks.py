"""The one task: render one pass of one tile of a job, store it, merge it.

``render_pass(job_id, tile, pass_index)`` is thin and idempotent: it takes ids, re-fetches the
scene from Redis (compiled once per process), renders the pass's sample range with
``renderer.render.render_tile``, writes the ``SampleBuffer`` under the deterministic key
``{prefix}:job:{id}:pass:{tile}:{pass}`` and merges it (``services.farm.merge.merge_pass``, exactly
once however often the task runs). Running it twice costs a render, never a double count.
"""

from __future__ import annotations

import contextlib
import logging
import time

import redis
from celery import signals
from celery.exceptions import Reject, SoftTimeLimitExceeded
from kombu.exceptions import OperationalError

from renderer.film.buffer import SampleBuffer
from services.farm.blocklist import HAND_BACK_PAUSE
from services.farm.frames import PatchError, apply_patch
from services.farm.passes import Delivery, HandBack, begin_pass, deliver, end_pass, pass_failed
from services.farm.planner import celery_priority
from services.farm.pools import queue_for
from services.farm.queue import continue_chain
from services.farm.settings import get_settings
from services.farm.store import FRAME_LOOKED
from services.farm.targets import adaptive_counts, settle_converged, wake_converged
from worker import runtime
from worker.celery_app import app

log = logging.getLogger(__name__)


@signals.worker_init.connect
def _init_worker(sender: object = None, **_: object) -> None:
    """In the worker node's main process, before the pool forks: its name (the pool processes
    inherit it), and a cold kernel cache filled once."""
    runtime.NODE = str(getattr(sender, "hostname", "") or "")
    if not get_settings().prewarm:
        return
    seconds = runtime.prewarm_cache(get_settings().worker_kernel)
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


# Redis unreachable (restarting, a network cut): nothing about the pass can be recorded, and no
# message sent (kombu's OperationalError: a publish that failed its retries; the broker is the
# same Redis).
REDIS_DOWN = (redis.ConnectionError, redis.TimeoutError, OperationalError)


@app.task(name="worker.tasks.render_pass", bind=True)
def render_pass(self, job_id: str, tile: int, pass_index: int) -> str:
    """Render, store and merge pass ``pass_index`` of tile ``tile`` of job ``job_id``.

    Returns what happened (``merged``, ``duplicate``, ``skipped: <status>``, ``failed``), for logs.
    """
    state = runtime.STATE
    deadline = time.monotonic() + state.settings.redis_outage_wait
    # "counted": begin_pass has counted this delivery; "again": it runs again after an outage
    begun: dict[str, bool] = {}
    while True:
        try:
            result = _render_pass(job_id, tile, pass_index, begun)
            if result == "duplicate" and begun.get("again"):
                # Merged before the outage, perhaps without queuing its tile's next pass (a job
                # with a target error runs each tile's passes as a chain): queue it unless merged
                continue_chain(state.store, app, job_id, tile, pass_index)
            return result
        except REDIS_DOWN as err:
            # Redis went away mid-pass (restarted, a network cut). The message cannot be given
            # back meanwhile: its channel died with the connection, so a rejection is lost and
            # the message waits in kombu's unacked hash for the stall rule (30 s once no live
            # worker holds a pass of its job) or the visibility timeout (an hour). Wait for
            # Redis and run the pass again instead: it is idempotent, and its message,
            # unacknowledged, comes back later as a duplicate. The outage is not the pass's
            # fault: a delivery already counted is not counted again.
            if not _wait_for_redis(state.store, deadline):
                raise Reject(f"Redis unreachable: {err}", requeue=True) from err
            begun["again"] = True
            log.warning("Redis was unreachable during job %s tile %d pass %d (%s); it is back: "
                        "running the pass again", job_id, tile, pass_index, err)


def _wait_for_redis(store, deadline: float) -> bool:
    """Ping Redis until it answers (True) or ``deadline`` (``time.monotonic``) passes (False)."""
    pause = 0.1
    while True:
        try:
            store.ping()
            return True
        except REDIS_DOWN:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(pause, left))
            pause = min(2 * pause, 2.0)


def _render_pass(job_id: str, tile: int, pass_index: int, begun: dict[str, bool]) -> str:
    t_task = time.perf_counter()
    tally: dict[str, float] = {}  # the farm's counters, filled once the pass is merged
    state = runtime.STATE
    store = state.store
    settings = state.settings

    node = runtime.NODE or state.worker_id
    delivery = begin_pass(store, settings, job_id, tile, pass_index, holder=state.worker_id,
                          node=node, count=not begun.get("counted"))
    if isinstance(delivery, Delivery):
        begun["counted"] = True
    try:
        if isinstance(delivery, str):
            return delivery
        if isinstance(delivery, HandBack):
            # Blocklisted for this job: the pass goes back to the job's queue for another node,
            # and this process waits a moment before it takes a message again
            render_pass.apply_async((job_id, tile, pass_index),
                                    priority=celery_priority(delivery.meta.priority),
                                    queue=queue_for(delivery.meta.tags))
            time.sleep(HAND_BACK_PAUSE)
            return "handed back (blocklisted)"
        state.set_task(f"{job_id}/{tile}/{pass_index}")
        return _render_and_merge(state, delivery.meta, tile, pass_index, t_task, tally)
    except REDIS_DOWN:
        raise  # not the pass's fault: not recorded as a failure (render_pass runs it again)
    except Exception as err:  # every other failure is recorded on the tile
        assert isinstance(delivery, Delivery)
        reason = ("timed out" if isinstance(err, SoftTimeLimitExceeded)
                  else f"{type(err).__name__}: {err}")
        if not pass_failed(store, settings, delivery, tile, pass_index, reason, node):
            return "failed"
        render_pass.apply_async((job_id, tile, pass_index), countdown=1.0,
                                priority=celery_priority(delivery.meta.priority),
                                queue=queue_for(delivery.meta.tags))
        return "retrying"
    finally:
        state.set_task("")
        # Redis down: the holding stays, and the next pass this process begins replaces it
        with contextlib.suppress(*REDIS_DOWN):
            end_pass(store, state.worker_id, **tally)


def _send_passes(todo: list[tuple[int, int]], meta) -> None:
    """Queue passes of a job (converged tiles asked again, ``settle_converged``)."""
    for tile, pass_index in todo:
        render_pass.apply_async((meta.id, tile, pass_index),
                                priority=celery_priority(meta.priority),
                                queue=queue_for(meta.tags))


def _render_and_merge(state: runtime.WorkerState, meta, tile: int, pass_index: int,
                      t_task: float, tally: dict[str, float]) -> str:
    from renderer.render import render_tile
    from renderer.scene import SceneError
    from renderer.scene.compile import CompileError

    store = state.store
    job_id = meta.id
    # A job of frames: the frame's scene is the job's with the frame's patch applied, compiled
    # once per process and frame
    frame = meta.plan.frame_of(tile)
    key = job_id if meta.plan.frames == 1 else f"{job_id}/{frame}"
    compiled = state.cached(key)
    try:
        if compiled is None:
            scene_json = store.get_scene(job_id)
            if scene_json is None:
                return "skipped: no scene"
            if meta.plan.frames > 1:
                patches = store.get_frames(job_id)
                if patches is None:
                    return "skipped: no frames"
                scene_json = apply_patch(scene_json, patches[frame])
            compiled = state.compiled(key, scene_json)
    except (SceneError, CompileError, PatchError) as err:
        # Not renderable, whichever tile asks: fail the job with the reason, keep the worker.
        store.fail_job(job_id, str(err))
        return "failed"

    x0, y0, w, h = meta.plan.tile_rect(tile)
    start, count = meta.plan.sample_range(pass_index)
    counts = None
    if compiled.target_error is not None:
        # Adaptive sampling: each pixel's share of this pass, from the tile's merged buffer
        counts = adaptive_counts(store, meta, tile, compiled.target_error, count)
        if not counts.any():
            # Nothing to add under the frame's scale now: the pass is merged empty and the tile
            # waits, converged, with its later passes unsent (each pass of a target job queues
            # the next). Once no tile renders, settle_converged asks every converged tile again
            # under the scale the other tiles' merges have moved it to: it queues those that
            # would take samples, or ends the job (their later passes count as merged, empty).
            if not deliver(store, state.settings, job_id, tile, pass_index,
                           SampleBuffer.empty(x0, y0, w, h)):
                return "duplicate"  # the delivery that merged it decided for the tile
            store.set_tile_state(job_id, tile, "converged")
            if store.frame_meta(meta, meta.plan.frame_of(tile)).pilot_error is None:
                # (stopped on its own first look, or to wait for the frames' pilot: a merge that
                # completed them while it was being marked did not see it converged)
                wake_converged(store, _send_passes, job_id, [tile], of_tile=tile)
            settle_converged(store, _send_passes, job_id, tile)
            return "converged"
    t0 = time.perf_counter()
    buf = render_tile(compiled, x0, y0, w, h, start, count, counts,
                      kernel=state.settings.worker_kernel)
    seconds = time.perf_counter() - t0
    paths = w * h * count if counts is None else int(counts.sum())
    state.count_pass(paths, seconds)

    merged = deliver(store, state.settings, job_id, tile, pass_index, buf)
    if merged & FRAME_LOOKED and meta.target_error is not None:
        # This merge completed the frames' first look or pilot: the tiles that stopped before it
        # on their own look, or to wait for it, are asked again on the frames'
        wake_converged(store, _send_passes, job_id, of_tile=tile)
    if merged and meta.target_error is not None and pass_index + 1 < meta.plan.n_passes:
        # A job with a target error: the tile's next pass, queued once (by the merge that
        # counted this one); it stops the tile when it finds nothing to add. A process that dies
        # between the merge and this still holds the pass: once its heartbeat has expired the
        # sweeper queues the next pass (lost_workers.requeue_lost, queue.continue_chain).
        render_pass.apply_async((job_id, tile, pass_index + 1),
                                priority=celery_priority(meta.priority),
                                queue=queue_for(meta.tags))
    elif merged and meta.target_error is not None:
        # The tile's last pass: with no tile left rendering, the converged ones are asked again
        settle_converged(store, _send_passes, job_id, tile)
    # task_seconds - render_seconds: the per-task overhead (Redis, buffers, merge, bookkeeping);
    # counted with the pass's end (end_pass, one round trip for both)
    tally.update(tasks_done=1, render_seconds=seconds, paths=paths,
                 task_seconds=time.perf_counter() - t_task)
    return "merged" if merged else "duplicate"
