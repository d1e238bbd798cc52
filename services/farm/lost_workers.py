"""Passes held by a worker process that died, sent again as soon as its heartbeat has expired.

Each worker process beats every ``heartbeat_interval`` into a hash that expires after three
intervals (``worker.runtime``), and records which pass it renders when the pass begins (the
``{p}:holding`` hash, written in the same Lua step that counts the delivery:
``JobStore.add_attempt``), clearing it when the pass ends. A process SIGKILLed with its node, or
cut off from Redis, stops beating; once its hash has expired, each sweep
(``services.farm.merge.sweep``) takes its holding and sends the pass again, unless the pass has
been merged, its job has ended, or another delivery of it has begun since (a pool process killed
alone has its message put back at once by Celery: ``task_reject_on_worker_lost``). A merged pass
of a job with a target error has its tile's next pass sent instead, unless merged: the process
may have died before queuing it (``queue.continue_chain``).

Without this, the message of a pass whose whole node died stays in kombu's ``unacked`` hash for
the visibility timeout (an hour), and the stall rule brings it back after ``stall_timeout`` (7
minutes) at best; here it comes back within about one heartbeat timeout plus a sweep interval
(``python -m bench.worker_loss``). The old message still comes back after the visibility timeout
and is dropped as a duplicate (merged already). A process that only stalled (SIGSTOP, a long
pause) and later finishes renders the pass twice; merging exactly once makes that harmless.
"""

from __future__ import annotations

import logging

from celery import Celery

from services.farm.queue import continue_chain, enqueue
from services.farm.store import ACTIVE, JobStore

log = logging.getLogger(__name__)


def requeue_lost(store: JobStore, celery: Celery) -> list[tuple[str, int, int]]:
    """Send again each pass held by a worker process whose heartbeat has expired; returns the
    (job, tile, pass) sent."""
    sent = []
    for worker_id, held in store.lost_holdings().items():
        if not store.claim_holding(worker_id, held):
            continue  # another sweeper took it, or the worker moved on meanwhile
        try:
            job_id, tile_s, pass_s, attempt_s = held.split(" ")
            tile, pass_index, attempt = int(tile_s), int(pass_s), int(attempt_s)
        except ValueError:
            log.warning("worker %s held %r: not a pass", worker_id, held)
            continue
        meta = store.get_job(job_id)
        if meta is None or meta.status not in ACTIVE:
            continue
        if store.is_merged(job_id, tile, pass_index):
            # Merged, then lost (perhaps before queuing its tile's next pass: a target job)
            if continue_chain(store, celery, job_id, tile, pass_index):
                sent.append((job_id, tile, pass_index + 1))
            continue
        if store.attempts(job_id, tile, pass_index) != attempt:
            continue  # delivered again since (the message put back when its process died)
        enqueue(celery, job_id, [(tile, pass_index)], meta.priority, meta.tags)
        store.count(lost_requeues=1)
        log.warning("worker %s lost (heartbeat expired) while rendering job %s tile %d pass %d "
                    "(try %d): sent again", worker_id, job_id, tile, pass_index, attempt)
        sent.append((job_id, tile, pass_index))
    return sent
