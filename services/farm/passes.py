"""The life of one pass on a worker: whether a delivery renders, what a failure does, and how
a rendered buffer reaches the job. The task (``worker/tasks.py``) calls these around the render;
the rules are here, beside the store they read and write.

- ``begin_pass``: a delivery of a job that is final (cancelled, failed, done, deleted) or of a
  pass not in its plan does nothing; one of a pass merged already is a duplicate; every other is
  counted (the redelivery cap: a pass that keeps killing its worker stops being retried), and
  past ``max_attempts`` fails its tile.
- ``pass_failed``: a failed try is noted on the tile and tried again, or past ``max_attempts``
  fails the tile.
- ``deliver``: the buffer is stored under the pass's deterministic key and merged exactly once.
"""

from __future__ import annotations

from dataclasses import dataclass

from renderer.film.adaptive import tile_converged
from renderer.film.buffer import SampleBuffer
from services.farm.merge import merge_pass
from services.farm.settings import Settings
from services.farm.store import FINAL, JobMeta, JobStore


@dataclass(frozen=True)
class Delivery:
    """A delivery that renders: the job as read when it began, and which try of the pass."""

    meta: JobMeta
    attempt: int


def begin_pass(store: JobStore, settings: Settings, job_id: str, tile: int,
               pass_index: int) -> Delivery | str:
    """A ``Delivery`` to render, or what happened instead (``skipped: …``, ``duplicate``,
    ``failed``), for the logs."""
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
    if attempt == 0:
        return "skipped: no such job"  # archived or deleted since it was read
    if attempt > settings.max_attempts:
        store.fail_tile(job_id, tile, f"pass {pass_index} gave up after {attempt - 1} tries "
                        "(its worker was lost or timed out each time)")
        return "failed"
    if meta.status == "queued":  # the job's first pass (one round trip fewer for the others)
        store.mark_started(job_id)
    store.set_tile_running(job_id, tile)
    return Delivery(meta, attempt)


def pass_failed(store: JobStore, settings: Settings, delivery: Delivery, tile: int,
                pass_index: int, reason: str) -> bool:
    """Record a try that raised; True if the pass is to be tried again, False if its tile
    failed (the last try)."""
    job_id = delivery.meta.id
    if delivery.attempt >= settings.max_attempts:
        store.fail_tile(job_id, tile, f"pass {pass_index}: {reason} "
                        f"(after {delivery.attempt} tries)")
        return False
    store.note_tile_error(job_id, tile, f"pass {pass_index}, try {delivery.attempt}: {reason}")
    return True


def converged(store: JobStore, job_id: str, tile: int, target_error: float) -> bool:
    """Adaptive sampling: the tile's merged buffer meets the scene's target (a pure rule of that
    buffer, ``renderer.film.adaptive.tile_converged``), so its later passes add no samples."""
    data = store.tile_buffer(job_id, tile)
    return data is not None and tile_converged(SampleBuffer.from_bytes(data), target_error)


def deliver(store: JobStore, settings: Settings, job_id: str, tile: int, pass_index: int,
            buf: SampleBuffer) -> bool:
    """Store the pass's buffer under its deterministic key and merge it; True if this call
    merged it (False: a duplicate)."""
    store.put_pass(job_id, tile, pass_index, buf.to_bytes(), ttl=settings.pass_ttl)
    return merge_pass(store, job_id, tile, pass_index)
