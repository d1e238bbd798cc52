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
- ``settle_converged``: a job with a target error whose tiles have all converged or ended asks
  its converged tiles again under the frame's final scale.
- ``wake_converged``: ... and once the frames' first look or pilot is known, those that stopped
  before it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from renderer.film.adaptive import frame_scale, noise_target, pass_counts
from renderer.film.buffer import SampleBuffer
from services.farm.blocklist import no_eligible_reason
from services.farm.merge import merge_pass
from services.farm.planner import chain_heads
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


def adaptive_counts(store: JobStore, meta: JobMeta, tile: int, target_error: float,
                    pass_samples: int) -> np.ndarray:
    """Adaptive sampling: the samples each pixel of the tile takes of this pass (``(h, w)``
    int32), a pure rule of the tile's merged buffer and the frame's scale from the job's tile
    summaries (``renderer.film.adaptive.pass_counts``, ``frame_scale``), nothing once the
    frame's estimated error from them (``JobMeta.expected_error``) is within the rule's slack of
    its aim: AIM × the target less the bias auto's models may add (``JobMeta.expected_bias``,
    ``noise_target``), as the local loop's. Before the tile's first merge the rule sees an
    empty buffer and gives the pilot's first half: ``FIRST_LOOK`` samples every pixel (at most
    the pass and ``render.spp``), as the local loop's, not the whole first pass (a packet
    scene's first pass of 32 samples took the Cornell box to 0.07x a target of 0.1); after it,
    nothing where the first look's bound is within the aim (the frame's,
    ``JobMeta.first_look_bound``, once every tile has merged its first look; before, the
    tile's own), else the rest of the pilot, ``PILOT`` samples a pixel; after that, a stop or
    every pixel one count, on the frame's estimate at the end of its pilot
    (``JobMeta.pilot_error``, once every tile has ended its pilot; before, nothing: the tile
    waits, ``wake_converged``)."""
    # (the samples' noise's share of the target: auto's models may take some of it)
    target_error = noise_target(target_error, meta.expected_bias)
    data = store.tile_buffer(meta.id, tile)
    buf = (SampleBuffer.empty(*meta.plan.tile_rect(tile)) if data is None
           else SampleBuffer.from_bytes(data))
    scale = None
    if meta.err_pixels >= meta.frame_pixels:
        # Every pixel of the frames has an estimate: the frame-wide allocation
        scale = frame_scale(meta.weight_sum, meta.err_pixels, target_error)
    return pass_counts(buf, target_error, meta.plan.spp, pass_samples, scale,
                       meta.expected_error, meta.first_look_bound, meta.pilot_error)


def settle_converged(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
                     job_id: str) -> list[tuple[int, int]]:
    """A job with a target error, once none of its tiles renders or waits for a pass: each tile
    that converged (``tile_state`` ``converged``: its rule found nothing to add) is asked again,
    under the frame's scale now, which the other tiles' merges have moved since. A tile the rule
    now gives samples is queued again at its next pass (``send``); when none is, each converged
    tile's remaining passes count as merged, empty (``skip_passes``), and the job is finished.
    Returns the passes sent. While a tile still has a chain (its next pass queued or rendering)
    this does nothing: that tile's end settles the job. Called by the worker after a tile
    converges and after a tile's last pass merges; two calls at once send a pass twice at most,
    and a pass is merged once."""
    meta = store.get_job(job_id)
    if meta is None or meta.target_error is None or meta.status not in ("queued", "running"):
        return []
    heads = dict(chain_heads(store.unmerged(job_id, meta.plan)))
    states = store.tile_states(job_id)
    if any(states.get(tile) != "converged" for tile in heads):
        return []
    again = _ask_again(store, send, meta, heads)
    if again:
        return again
    for tile, pass_index in heads.items():
        store.skip_passes(job_id, tile, pass_index, meta.plan.n_passes)
    for tile, state in states.items():
        # a tile converged at its last pass, or one whose chain ended at it with fewer samples
        # than render.spp (its merge left it queued)
        if tile not in heads and state not in ("done", "failed"):
            store.set_tile_state(job_id, tile, "done")
    store.finish_if_complete(job_id)
    return []


def _ask_again(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
               meta: JobMeta, heads: dict[int, int]) -> list[tuple[int, int]]:
    """Run the rule again on each converged tile of ``heads`` (tile: its next pass) and queue
    those it now gives samples at that pass; returns them."""
    again: list[tuple[int, int]] = []
    if meta.target_error is None:
        return again
    for tile, pass_index in heads.items():
        counts = adaptive_counts(store, meta, tile, meta.target_error,
                                 meta.plan.sample_range(pass_index)[1])
        if counts.any():
            again.append((tile, pass_index))
    for tile, _ in again:
        store.set_tile_state(meta.id, tile, "queued")
    if again:
        send(again, meta)
    return again


def wake_converged(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
                   job_id: str, tiles: list[int] | None = None) -> list[tuple[int, int]]:
    """A job with a target error whose frames' first look or pilot became known (a merge that
    completed them: ``FRAME_LOOKED``): its converged tiles (or those of ``tiles`` that are)
    asked again on it at once, not at the end of the job (``settle_converged``), and those the
    rule now gives samples queued at their next pass (``send``). They stopped on their own
    first look's bound, or at the end of their pilot to wait for the frames' estimate there
    (``renderer.film.adaptive.pass_counts``). Returns the passes sent. ``tiles``: a tile that
    stopped to wait asks for itself after it is marked converged, so that a merge that
    completed the frames' pilot meanwhile, and asked before it was marked, does not leave it
    waiting. Two calls at once send a pass twice at most, and a pass is merged once."""
    meta = store.get_job(job_id)
    if (meta is None or meta.target_error is None or meta.status not in ("queued", "running")
            or meta.first_look_bound is None):
        return []
    states = store.tile_states(job_id)
    heads = {tile: p for tile, p in chain_heads(store.unmerged(job_id, meta.plan))
             if states.get(tile) == "converged" and (tiles is None or tile in tiles)}
    return _ask_again(store, send, meta, heads)


def deliver(store: JobStore, settings: Settings, job_id: str, tile: int, pass_index: int,
            buf: SampleBuffer) -> int:
    """Store the pass's buffer under its deterministic key and merge it; non-zero if this call
    merged it (0: a duplicate), with ``FRAME_LOOKED`` added where the merge completed the frames'
    first look or pilot (``wake_converged``). The merge's first read stores it (``put_pass``'s
    keys, one round trip fewer), so that the sweeper merges it should this process die before
    the merge's EXEC."""
    return merge_pass(store, job_id, tile, pass_index, buf.to_bytes(), ttl=settings.pass_ttl)
