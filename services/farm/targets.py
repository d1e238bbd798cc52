"""Jobs with a target error (``render.target_error``): the farm's adaptive rule on a tile's
merged buffer, and the converged tiles asked again. The worker calls these around a pass
(``worker/tasks.py``); so does ``services.farm.queue.continue_chain``, for a pass whose worker did
not (the sweeper merged it, or its worker was lost after merging it).

- ``adaptive_counts``: the samples each pixel of a tile takes of its next pass
  (``renderer.film.adaptive.pass_counts`` on the tile's merged buffer and the job's sums).
- ``settle_converged``: a job with a target error whose tiles have all converged or ended asks
  its converged tiles again under the frame's final scale (a target job of frames: each frame
  whose tiles have, on its own).
- ``wake_converged``: ... and once the frames' first look or pilot is known, those that stopped
  before it (a target job of frames: that frame's).

This module imports neither the merge nor the queue, so that both can call it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from renderer.film.adaptive import frame_scale, noise_target, pass_counts
from renderer.film.buffer import SampleBuffer
from services.farm.planner import chain_heads
from services.farm.store import JobMeta, JobStore


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
    # (a job of frames: the sums of the tile's frame, each frame sampled to the target on its
    # own; JobStore.frame_meta)
    meta = store.frame_meta(meta, meta.plan.frame_of(tile))
    data = store.tile_buffer(meta.id, tile)
    buf = (SampleBuffer.empty(*meta.plan.tile_rect(tile)) if data is None
           else SampleBuffer.from_bytes(data))
    scale = None
    if meta.err_pixels >= meta.frame_pixels:
        # Every pixel of the frames has an estimate: the frame-wide allocation
        scale = frame_scale(meta.weight_sum, meta.err_pixels, target_error)
    return pass_counts(buf, target_error, meta.plan.spp, pass_samples, scale,
                       meta.expected_error, meta.first_look_bound, meta.pilot_error)


def _scope(store: JobStore, meta: JobMeta, tile: int | None
           ) -> tuple[JobMeta, dict[int, int], dict[int, str]]:
    """The job as its rule reads it, and the chain heads (tile: its next pass) and tile states
    that a call about ``tile`` looks at: in a target job of frames, each frame's tiles reading
    their frame's sums, that tile's frame's (its sums read once for all its tiles; one frame's
    passes and states read, not the job's: a job of many frames settles and wakes each frame in
    time linear in its own tiles); else the job's."""
    if tile is not None and meta.frame_sums:
        frame = meta.plan.frame_of(tile)
        todo, states = store.chain_view(meta.id, meta.plan, frame)
        return store.frame_meta(meta, frame), dict(chain_heads(todo)), states
    todo, states = store.chain_view(meta.id, meta.plan)
    return meta, dict(chain_heads(todo)), states


def settle_converged(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
                     job_id: str, tile: int | None = None) -> list[tuple[int, int]]:
    """A job with a target error, once none of its tiles renders or waits for a pass: each tile
    that converged (``tile_state`` ``converged``: its rule found nothing to add) is asked again,
    under the frame's scale now, which the other tiles' merges have moved since. A tile the rule
    now gives samples is queued again at its next pass (``send``); when none is, each converged
    tile's remaining passes count as merged, empty (``skip_passes``), and the job is finished.
    Returns the passes sent. While a tile still has a chain (its next pass queued or rendering)
    this does nothing: that tile's end settles the job. Called by the worker after a tile
    converges and after a tile's last pass merges (``tile``: in a target job of frames, that
    tile's frame is settled, on its own sums, whatever the other frames' tiles do); two calls
    at once send a tile's pass once (``_ask_again``)."""
    meta = store.get_job(job_id)
    if meta is None or meta.target_error is None or meta.status not in ("queued", "running"):
        return []
    meta, heads, states = _scope(store, meta, tile)
    if any(states.get(t) != "converged" for t in heads):
        return []
    again, taken = _ask_again(store, send, meta, heads)
    if again or taken:
        # (taken: a tile the rule gives samples that another caller has queued, or whose merge
        # has moved it on, since it was read: the job goes on, and that tile's end settles it)
        return again
    for t, pass_index in heads.items():
        store.skip_passes(job_id, t, pass_index, meta.plan.n_passes)
    for t, state in states.items():
        # a tile converged at its last pass, or one whose chain ended at it with fewer samples
        # than render.spp (its merge left it queued)
        if t not in heads and state not in ("done", "failed"):
            store.set_tile_state(job_id, t, "done")
    store.finish_if_complete(job_id)
    return []


def _ask_again(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
               meta: JobMeta, heads: dict[int, int]) -> tuple[list[tuple[int, int]], int]:
    """Run the rule again on each converged tile of ``heads`` (tile: its next pass) and queue
    those it now gives samples at that pass: the passes sent, and how many tiles it gave
    samples that were not sent. Each is sent only where it is still converged at that pass
    (``JobStore.requeue_converged``, one step): the rule read them a moment ago, and another
    caller may have queued it since, or a merge moved it on (a pass sent for a next pass that
    had merged meanwhile was dropped as a duplicate, and its tile, marked queued, waited with
    nothing in flight for the stall rule: 7 of 33 caustic floor jobs at 0.1 took 30 s on two
    worker processes)."""
    again: list[tuple[int, int]] = []
    taken = 0
    if meta.target_error is None:
        return again, taken
    for tile, pass_index in heads.items():
        counts = adaptive_counts(store, meta, tile, meta.target_error,
                                 meta.plan.sample_range(pass_index)[1])
        if not counts.any():
            continue
        if store.requeue_converged(meta.id, tile, pass_index):
            again.append((tile, pass_index))
        else:
            taken += 1
    if again:
        send(again, meta)
    return again, taken


def wake_converged(store: JobStore, send: Callable[[list[tuple[int, int]], JobMeta], None],
                   job_id: str, tiles: list[int] | None = None,
                   of_tile: int | None = None) -> list[tuple[int, int]]:
    """A job with a target error whose frames' first look or pilot became known (a merge that
    completed them: ``FRAME_LOOKED``): its converged tiles (or those of ``tiles`` that are)
    asked again on it at once, not at the end of the job (``settle_converged``), and those the
    rule now gives samples queued at their next pass (``send``). They stopped on their own
    first look's bound, or at the end of their pilot to wait for the frames' estimate there
    (``renderer.film.adaptive.pass_counts``). Returns the passes sent. ``tiles``: a tile that
    stopped to wait asks for itself after it is marked converged, so that a merge that
    completed the frames' pilot meanwhile, and asked before it was marked, does not leave it
    waiting. ``of_tile``: the tile whose merge completed them, or that asks for itself; in a
    target job of frames only its frame's tiles are asked (each frame's tiles read their
    frame's sums, and the others' did not change: a job of many frames does not ask every
    converged tile at each frame's look and pilot). Two calls at once send a tile's pass once
    (``_ask_again``)."""
    meta = store.get_job(job_id)
    if (meta is None or meta.target_error is None or meta.status not in ("queued", "running")
            # (nothing is known yet; a job of frames' own first looks are in its frames' sums)
            or (meta.first_look_bound is None and not meta.frame_sums)):
        return []
    asked = None if tiles is None else set(tiles)
    meta, heads, states = _scope(store, meta, of_tile)
    heads = {t: p for t, p in heads.items()
             if states.get(t) == "converged" and (asked is None or t in asked)}
    return _ask_again(store, send, meta, heads)[0]
