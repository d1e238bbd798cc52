"""Merging pass buffers into per-tile accumulations, exactly once, and the image they make.

Who merges: the worker that rendered a pass merges it right away (``merge_pass``), so the farm
makes progress whether or not the service is up; the service's ``Sweeper`` merges any pass buffer
left behind (a worker that died between writing its pass and merging it) when it starts and every
``sweep_interval`` seconds after. Both call the same ``merge_pass``.

Why a pass is merged at most once, whoever calls and however often: the merge is an optimistic
Redis transaction. It WATCHes the tile's accumulation and the job's ``merged`` set, reads both,
adds the pass in Python, and in one MULTI/EXEC writes the new accumulation, adds ``tile:pass`` to
``merged``, bumps the counters and deletes the pass buffer. If anyone else changed either key in
between, EXEC fails and the merge starts over, and then finds ``tile:pass`` already in ``merged``
and only deletes the buffer. So a task delivered twice writes the same pass twice (same key, same
bytes: rendering is deterministic) and it is counted once.

Why the sweeper also re-queues passes: a task message can vanish. kombu's Redis transport takes a
message with ``BRPOP`` (Redis removes it from the list as it replies) and only then, in the
consumer's callback, writes it to the ``unacked`` hash (``QoS.append``) from which
``restore_visible`` brings back the messages of dead workers after ``visibility_timeout``. A worker
node killed between the two (its main process, which does both) takes the message with it, and
nothing in Celery sends it again; so does one killed while it holds the restore mutex (the other
nodes restore nothing for ``unacked_mutex_expire``, 300 s). The service knows every planned
(tile, pass) and which are merged, so ``requeue_stalled`` sends again the unmerged passes of a job
that has been idle (no pass started or merged) for ``stall_timeout`` while no message of its
priority or above waits in the queue, or for ``stall_unheld_timeout`` (30 s) if besides no live
worker process holds a pass of it; merging once makes the duplicates harmless. The same rule
brings back, before the visibility timeout, the passes of a worker node that died as a whole,
and a message left in kombu's ``unacked`` hash by a task whose Redis connection died (its
acknowledgement or rejection lost with the channel).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import redis
from celery import Celery

from renderer.film.buffer import SampleBuffer
from services.farm.lost_workers import requeue_lost
from services.farm.planner import chain_heads
from services.farm.queue import (
    continue_chain,
    enqueue,
    pool_frames_beside_old_workers,
    waiting_ahead,
)
from services.farm.store import FRAME_LOOKED, MERGED_LAST, JobStore

log = logging.getLogger(__name__)


def merge_pass(store: JobStore, job_id: str, tile: int, pass_index: int,
               data: bytes | None = None, ttl: float | None = None) -> int:
    """Merge one pass buffer into its tile's accumulation if not merged yet (``data``: its bytes
    as stored, when the caller has them; with ``ttl``, not stored yet: the merge stores them
    first, for ``ttl`` seconds). Non-zero if this call merged it: 1, with ``FRAME_LOOKED`` added
    where the merge completed the frames' first look or pilot (the tiles stopped before it are
    to be asked again: ``services.farm.targets.wake_converged``); 0 if it was merged already or
    there is no buffer to merge."""
    merged = store.merge_pass_buffer(job_id, tile, pass_index, data, ttl)
    if not merged:
        return 0
    if merged & MERGED_LAST:
        # After the transaction, idempotent by itself (and redone by the sweeper if this process
        # dies first): the job done once every pass is merged.
        store.finish_if_complete(job_id)
    return 1 | (merged & FRAME_LOOKED)


@dataclass(frozen=True)
class StallRule:
    """When the sweeper re-queues a job's passes (``Settings.stall_timeout``,
    ``Settings.max_stall_requeues``, ``Settings.stall_unheld_timeout``) and the Celery app it
    sends them with."""

    celery: Celery
    timeout: float
    max_requeues: int
    unheld_timeout: float | None = None
    """The stall time of a job no live worker process renders a pass of, at most ``timeout``;
    None: ``timeout``."""

    @property
    def shortest(self) -> float:
        """The unheld stall time as applied: never above ``timeout``."""
        return self.timeout if self.unheld_timeout is None else min(self.timeout,
                                                                    self.unheld_timeout)


def requeue_stalled(store: JobStore, rule: StallRule, job_id: str,
                    now: float | None = None) -> list[tuple[int, int]]:
    """If the job is stalled, send its unmerged passes again and return them; past
    ``max_requeues`` stalls in a row, fail the job with the reason instead.

    Stalled: queued or running, no pass of it started or merged for ``rule.timeout`` (longer than
    a pass may run), or for ``rule.unheld_timeout`` while no live worker process holds a pass of
    it (none can be running: a message stuck in kombu's ``unacked`` hash, or lost), and no
    message at its priority level or above in the queue, so that none of its passes can be
    waiting behind other work. The re-queue does not spend a try of a pass (``attempts`` counts
    deliveries that run), and a pass delivered twice is merged once."""
    now = time.time() if now is None else now
    clock = store.stall_clock(job_id)
    if clock is None:
        return []
    priority, since, tags = clock
    if now - since < rule.shortest:
        return []  # the cheap test first: the queue is looked at only for idle jobs
    timeout = rule.timeout
    if now - since < timeout:
        if store.job_held(job_id):
            return []  # a live worker renders a pass of it: wait for the pass's time limit
        timeout = rule.shortest
    if waiting_ahead(rule.celery, store, priority, tags):
        return []
    stalls = store.claim_stall(job_id, timeout, now)
    if not stalls:
        return []  # another sweeper claimed it, or the job moved meanwhile
    if stalls > rule.max_requeues:
        store.fail_job(job_id, f"stalled: no pass started or merged for {timeout:g} s "
                       f"after {rule.max_requeues} re-queues of its unmerged passes")
        return []
    meta = store.get_job(job_id)
    if meta is None:
        return []
    todo = store.unmerged(job_id, meta.plan)
    if meta.target_error is not None:
        todo = chain_heads(todo)  # a job with a target: each tile's next pass, which queues on
    enqueue(rule.celery, job_id, todo, priority, tags)
    store.count(stall_requeues=1, passes_requeued=len(todo))
    log.warning("job %s stalled for %.0f s (%d in a row): %d unmerged passes sent again",
                job_id, now - since, stalls, len(todo))
    return todo


def sweep(store: JobStore, stall: StallRule | None = None) -> int:
    """Merge every pass buffer listed as pending; finish jobs whose last merge was interrupted;
    with a ``stall`` rule, re-queue the passes of stalled jobs. Returns how many passes this
    sweep merged."""
    merged = 0
    for key in store.pending_passes():
        # {prefix}:job:{id}:pass:{tile}:{pass}; the prefix may itself hold colons.
        parts = key[len(store.prefix) + 1:].split(":")
        if len(parts) != 5 or parts[0] != "job" or parts[2] != "pass":
            store.forget_pending(key)
            continue
        try:
            job_id, tile, pass_index = parts[1], int(parts[3]), int(parts[4])
            if merge_pass(store, job_id, tile, pass_index):
                merged += 1
                if stall is not None:
                    continue_chain(store, stall.celery, job_id, tile, pass_index)
        except Exception:  # a corrupt buffer must not stop the sweeper
            log.exception("cannot merge %s", key)
    if stall is not None:
        requeue_lost(store, stall.celery)  # passes of workers whose heartbeat expired
        # (a worker whose merge keeps no frames' sums, beside target jobs of frames that do)
        pool_frames_beside_old_workers(store, stall.celery)
    for job_id in store.active_job_ids():
        if not store.finish_if_complete(job_id) and stall is not None:
            requeue_stalled(store, stall, job_id)
    return merged


class Sweeper:
    """The service's background merger: ``sweep`` at start and every ``interval`` seconds, each
    time followed by the ``chores`` (finished jobs to the blob store, retention:
    ``services.farm.archive.chores``)."""

    def __init__(self, store: JobStore, interval: float, stall: StallRule | None = None,
                 chores: Sequence[Callable[[], object]] = ()):
        self.store = store
        self.interval = interval
        self.stall = stall
        self.chores = list(chores)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._sweep()  # carry on from Redis before serving
        self._thread = threading.Thread(target=self._run, name="lucent-sweeper", daemon=True)
        self._thread.start()

    def _sweep(self) -> None:
        sweep(self.store, self.stall)
        for chore in self.chores:
            try:
                chore()
            except Exception:  # one failing chore must not stop the merging
                log.exception("sweeper chore %r failed", chore)

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                self._sweep()
            except redis.RedisError as err:
                log.warning("sweep failed: %s", err)

    def stop(self) -> None:
        """Stop sweeping, then run the chores once more: a farm stopped just after a job
        finished (``lucent demo`` stops as soon as its job is done) leaves the job's record up
        to date and a done job archived. Before, the record stayed as the last sweep had seen
        it (running), and the next farm on the same data folder, with a Redis of its own, marked
        the job failed as lost. Not the merge sweep: nothing is requeued on the way out. A
        chore that fails (Redis or the database gone first) ends them with one line in the
        log, and the stop goes on."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        try:
            for chore in self.chores:
                chore()
        except Exception as err:  # (on the way out: a line, not a traceback)
            log.warning("the sweeper's last chores at stop did not run: %s", err)


def assemble(store: JobStore, job_id: str, frame_index: int = 0
             ) -> tuple[SampleBuffer, int] | None:
    """A frame's merged ``SampleBuffer`` as it stands (the first, or the only one), and the
    ``version`` it shows; None for an unknown job or frame."""
    meta = store.get_job(job_id)
    if meta is None or not 0 <= frame_index < meta.plan.frames:
        return None
    plan = meta.plan
    frame = SampleBuffer.empty(0, 0, plan.width, plan.height)
    first = frame_index * plan.tiles_per_frame
    buffers = store.tile_buffers(job_id, plan.tiles_per_frame, first)
    if buffers is None:
        # Archived, parked or deleted since its hash was read: a frame of missing tiles is not
        # its image
        return None
    for data in buffers:
        if data is not None:
            frame.add(SampleBuffer.from_bytes(data))
    return frame, meta.version
