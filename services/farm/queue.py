"""Sending tasks: the service enqueues ``render_pass`` by name, so it never imports the path
tracer (the API process stays light)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable

from celery import Celery

from services.farm.planner import celery_priority
from services.farm.pools import eligible, live, queue_for, worker_protocol
from services.farm.settings import Settings
from services.farm.store import ACTIVE, FRAME_SUMS_PROTOCOL, JobMeta, JobStore
from services.farm.targets import settle_converged, wake_converged

log = logging.getLogger(__name__)

TASK = "worker.tasks.render_pass"
# Messages sent ahead of the rest of a job's (``enqueue``)
FIRST_BATCH = 8


def celery_client(settings: Settings) -> Celery:
    """A Celery app with the workers' configuration for ``settings``, used only to send."""
    from services.farm.celery_config import celery_config

    app = Celery("lucent")
    app.config_from_object("services.farm.celery_config")
    app.conf.update(celery_config(settings))
    return app


def enqueue(app: Celery, job_id: str, tasks: list[tuple[int, int]], priority: int,
            tags: tuple[str, ...] = ()) -> None:
    """Send ``render_pass(job_id, tile, pass)`` for each pair, in the given order, to the queue
    of the job's tags (``services.farm.pools``).

    In one batch (kombu's ``Producer.batch``, from kombu 5.7: the messages' ``LPUSH``es go in
    pipelines of up to 1000 instead of a round trip each) and with the queue declared once
    instead of once a message: a 1080p job of 1024 spp (9180 tasks) is sent in ~1.3 s instead of
    ~3.7 s (docs/performance.md, "Sending a job's tasks"). Were Redis to fail within a batch, some
    of its messages may have been sent: the job's passes left unsent come back by the stall
    rule, and a pass sent twice is merged once."""
    level = celery_priority(priority)
    queue = queue_for(tags)
    with app.producer_or_acquire() as producer:
        producer.maybe_declare(app.amqp.queues[queue])
        batch = getattr(producer, "batch", None)  # kombu < 5.7: one round trip a message
        # The first FIRST_BATCH messages go out on their own, so that idle workers start while
        # the rest are built (~0.15 ms a message: 8.7 ms for the 60 of the default job, which
        # its workers spent waiting; docs/performance.md, "Sending a job's tasks")
        for part in (tasks[:FIRST_BATCH], tasks[FIRST_BATCH:]):
            with batch() if batch is not None else contextlib.nullcontext():
                for tile, pass_index in part:
                    app.send_task(TASK, args=(job_id, tile, pass_index), priority=level,
                                  queue=queue, producer=producer, declare=[])


def waiting_ahead(app: Celery, store: JobStore, priority: int, tags: tuple[str, ...] = ()) -> int:
    """Messages in Celery's queue that a worker takes before or along with the passes of a job of
    this priority: 0 means none of the job's passes is waiting in the queue (each is running,
    held by a worker, or lost). kombu keeps one Redis list per priority level (``celery``,
    ``celery:1``, ... ``celery:9``, with ``priority_steps`` 0..9 and ``sep`` ``:``) and serves
    them in that order; a job's passes are all sent at its level, to the queue of its tags."""
    queue = queue_for(tags)
    sep = app.conf.broker_transport_options.get("sep", ":")
    return store.broker_messages([queue if level == 0 else f"{queue}{sep}{level}"
                                  for level in range(celery_priority(priority) + 1)])


def _sender(celery: Celery) -> Callable[[list[tuple[int, int]], JobMeta], None]:
    """What ``targets``' wake and settle send the passes they ask again with: ``enqueue``."""

    def send(todo: list[tuple[int, int]], job: JobMeta) -> None:
        enqueue(celery, job.id, todo, job.priority, job.tags)

    return send


def pool_frames_beside_old_workers(store: JobStore, celery: Celery) -> list[str]:
    """Where a live worker's merge keeps no frames' sums (its heartbeat's protocol below
    ``FRAME_SUMS_PROTOCOL``: a farm upgraded worker by worker, an old worker that joined after
    the job was stored), each active target job of frames it takes pools them from now on
    (``JobStore.pool_frame_sums``), as the sums of the job that every merge keeps, and its
    converged tiles are asked again on those (``targets.wake_converged``, job-wide). Else its
    merges would leave its frames' sums short, and a frame whose first look or pilot never
    completed would end at the pilot. The sweeper's, each sweep; returns the jobs pooled."""
    old = [w for w in live(store.workers()) if (worker_protocol(w) or 1) < FRAME_SUMS_PROTOCOL]
    if not old:
        return []
    pooled = []
    for meta in store.get_jobs(store.active_job_ids()).values():
        takers = eligible(old, meta.tags) if meta.frame_sums else []
        if not takers or not store.pool_frame_sums(meta.id):
            continue
        log.warning("job %s: worker %s merges without the frames' own sums (protocol %s): the "
                    "job pools them from now on", meta.id, takers[0].get("id"),
                    worker_protocol(takers[0]))
        wake_converged(store, _sender(celery), meta.id)
        pooled.append(meta.id)
    return pooled


def continue_chain(store: JobStore, celery: Celery, job_id: str, tile: int,
                   pass_index: int) -> bool:
    """After a pass merged whose worker may not have done what its merge leaves to it (the
    sweeper merged it, or its worker was lost): for a job with a target error, whose passes of a
    tile queue one another (``planner.chain_heads``), queue the tile's next pass unless it is
    merged, and ask its converged tiles again as that worker would have: at once those that
    stopped before the frames' first look or pilot, which the merge may have completed
    (``targets.wake_converged``; a lost worker's merge's ``FRAME_LOOKED`` is not known here, so
    they are asked whatever it was, and the rule gives nothing to a tile that is still to wait),
    and after the tile's last pass every one once no tile renders (``targets.settle_converged``).
    True if it queued the next pass. (Sent twice, a pass is merged once, and only the merge that
    counts it queues the pass after it.)"""
    meta = store.get_job(job_id)
    if meta is None or meta.target_error is None or meta.status not in ACTIVE:
        return False
    send = _sender(celery)
    wake_converged(store, send, job_id, of_tile=tile)
    if pass_index + 1 >= meta.plan.n_passes:
        settle_converged(store, send, job_id, tile)
        return False
    if store.is_merged(job_id, tile, pass_index + 1):
        return False
    enqueue(celery, job_id, [(tile, pass_index + 1)], meta.priority, meta.tags)
    return True
