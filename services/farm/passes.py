"""The life of one pass on a worker: whether a delivery renders, what a failure does, and how
a rendered buffer reaches the job. The task (``worker/tasks.py``) calls these around the render;
the rules are here, beside the store they read and write.

- ``begin_pass``: a delivery of a job that is final (cancelled, failed, done, deleted) or of a
  pass not in its plan does nothing; one of a pass merged already is a duplicate; every other is
  counted (the redelivery cap: a pass that keeps killing its worker stops being retried), and
  past ``max_attempts`` fails its tile.
- ``pass_failed``: a failed try is noted on the tile and tried again, or past ``max_attempts``
  fails the tile.
- a delivery to a node blocklisted for the job is handed back (``services.farm.blocklist``), and a
  failed try counts against its node as well as its pass.
- ``deliver``: the buffer is stored under the pass's deterministic key and merged exactly once
  (both in the merge's round trips).

A job with a target error's rule for the pass, and its converged tiles asked again, are in
``services.farm.targets``.
"""

from __future__ import annotations

from dataclasses import dataclass

from renderer.film.buffer import SampleBuffer
from services.farm.blocklist import no_eligible_reason
from services.farm.merge import merge_pass
from services.farm.settings import Settings
from services.farm.store import FINAL, JobMeta, JobStore


@dataclass(frozen=True)
class Delivery:
    """A delivery that renders: the job as read when it began, and which try of the pass."""

    meta: JobMeta
    attempt: int


@dataclass(frozen=True)
class HandBack:
    """A delivery to a node blocklisted for the job: send the pass again for another node."""

    meta: JobMeta


def begin_pass(store: JobStore, settings: Settings, job_id: str, tile: int,
               pass_index: int, holder: str = "", node: str = "",
               count: bool = True) -> Delivery | HandBack | str:
    """A ``Delivery`` to render, a ``HandBack``, or what happened instead (``skipped: …``,
    ``duplicate``, ``failed``), for the logs. ``holder``: the worker process, recorded as holding
    the pass from the moment its delivery is counted until ``end_pass`` (a holder whose heartbeat
    expires meanwhile has its pass sent again: ``services.farm.lost_workers``). ``node``: its
    worker node, the blocklist's unit. ``count=False``: a delivery already counted, begun again
    after a Redis outage (not a try of its own)."""
    # The checks below and the count of the delivery in one round trip: the store counts it
    # only when the same checks pass there (None: not counted)
    meta, blocked, merged, attempt = store.begin_view(job_id, tile, pass_index, node, holder,
                                                      count)
    if meta is None or meta.status in FINAL:
        return f"skipped: {meta.status if meta else 'no such job'}"
    if blocked:
        reason = no_eligible_reason(store, meta, settings.blocklist_threshold)
        if reason is not None:
            store.fail_job(job_id, reason)
            return "failed"
        return HandBack(meta)
    # Not a pass of this job's plan (a message sent for another plan of the same id, by hand or
    # by an older service): nothing to render, and no reason to fail the job's tiles over it.
    if not (0 <= tile < meta.plan.n_tiles and 0 <= pass_index < meta.plan.n_passes):
        return "skipped: no such pass"
    # Delivered again after it was merged (a redelivery): nothing to do.
    if merged:
        return "duplicate"
    # Count every delivery, so that a pass that keeps killing its worker stops being retried. Only
    # deliveries that run are counted (one lost by the broker, then re-queued by the sweeper, is
    # not), and counting one marks the job alive for the sweeper's stall rule.
    # (and the tile becomes running if it is queued, in the same step)
    if attempt is None:  # a check passed here but not in the store (a plan without tile states)
        attempt = store.add_attempt(job_id, tile, pass_index, holder, running=True, count=count)
    if attempt > settings.max_attempts:
        store.fail_tile(job_id, tile, f"pass {pass_index} gave up after {attempt - 1} tries "
                        "(its worker was lost or timed out each time)")
        return "failed"
    if meta.status == "queued":  # the job's first pass (one round trip fewer for the others)
        store.mark_started(job_id)
    return Delivery(meta, attempt)


def end_pass(store: JobStore, holder: str, **increments: float) -> None:
    """The holder's pass ended (merged, failed, retried or skipped): it holds nothing;
    ``increments``: the farm's counters to add (``JobStore.count``), in the same round trip."""
    store.release_pass(holder, **increments)


def pass_failed(store: JobStore, settings: Settings, delivery: Delivery, tile: int,
                pass_index: int, reason: str, node: str = "") -> bool:
    """Record a try that raised on ``node``; True if the pass is to be tried again, False if its
    tile or job failed (the pass's last try; no eligible node left)."""
    job_id = delivery.meta.id
    threshold = settings.blocklist_threshold
    blocked = bool(node) and store.note_failure(job_id, node, threshold) >= threshold
    why = no_eligible_reason(store, delivery.meta, threshold) if blocked else None
    if blocked and why is None:
        # The node's fault, not the pass's: the try is taken back, and another node renders it
        store.forgive_attempt(job_id, tile, pass_index)
        store.note_tile_error(job_id, tile, f"pass {pass_index} on {node}: {reason} (the node "
                              f"is blocklisted for this job)")
        return True
    if delivery.attempt < settings.max_attempts and why is not None:
        store.note_tile_error(job_id, tile, f"pass {pass_index} on {node}: {reason}")
        store.fail_job(job_id, f"{why}; the last error: {reason}")
        return False
    if delivery.attempt >= settings.max_attempts:
        store.fail_tile(job_id, tile, f"pass {pass_index}: {reason} "
                        f"(after {delivery.attempt} tries)")
        return False
    store.note_tile_error(job_id, tile, f"pass {pass_index}, try {delivery.attempt}: {reason}")
    return True


def deliver(store: JobStore, settings: Settings, job_id: str, tile: int, pass_index: int,
            buf: SampleBuffer) -> int:
    """Store the pass's buffer under its deterministic key and merge it; non-zero if this call
    merged it (0: a duplicate), with ``FRAME_LOOKED`` added where the merge completed the frames'
    first look or pilot (``services.farm.targets.wake_converged``). The merge's first read
    stores it (``put_pass``'s keys, one round trip fewer), so that the sweeper merges it should
    this process die before the merge's EXEC."""
    return merge_pass(store, job_id, tile, pass_index, buf.to_bytes(), ttl=settings.pass_ttl)
