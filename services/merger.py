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
"""

from __future__ import annotations

import logging
import threading

import numpy as np
import redis

from renderer.film.buffer import SampleBuffer
from services.store import JobStore, pass_member

log = logging.getLogger(__name__)


def merge_pass(store: JobStore, job_id: str, tile: int, pass_index: int) -> bool:
    """Merge one pass buffer into its tile's accumulation if not merged yet. True if this call
    merged it; False if it was merged already or there is no buffer to merge."""
    r = store.r
    pass_key = store.pass_key(job_id, tile, pass_index)
    acc_key = store.acc_key(job_id, tile)
    merged_key = store.k("job", job_id, "merged")
    member = pass_member(tile, pass_index)
    job_key = store.job_key(job_id)
    with r.pipeline() as pipe:
        while True:
            try:
                pipe.watch(acc_key, merged_key)
                if pipe.sismember(merged_key, member):
                    pipe.unwatch()
                    r.delete(pass_key)
                    r.srem(store.k("pending"), pass_key)
                    return False
                data = pipe.get(pass_key)
                if data is None:
                    pipe.unwatch()
                    r.srem(store.k("pending"), pass_key)
                    return False
                if not pipe.exists(job_key):  # the job was deleted
                    pipe.unwatch()
                    r.delete(pass_key)
                    r.srem(store.k("pending"), pass_key)
                    return False
                buf = SampleBuffer.from_bytes(data)
                acc_bytes = pipe.get(acc_key)
                if acc_bytes is None:
                    acc = buf
                else:
                    acc = SampleBuffer.from_bytes(acc_bytes)
                    acc.add(buf)
                # Samples per pixel this pass planned: drawn ones, added or dropped as non-finite.
                spp_added = int((buf.count + buf.dropped).max()) if buf.count.size else 0
                pipe.multi()
                pipe.set(acc_key, acc.to_bytes())
                pipe.sadd(merged_key, member)
                pipe.delete(pass_key)
                pipe.srem(store.k("pending"), pass_key)
                pipe.hincrby(store.k("job", job_id, "tile_samples"), str(tile), spp_added)
                pipe.hincrby(job_key, "tasks_merged", 1)
                pipe.hincrby(job_key, "samples_merged", int(buf.count.sum()))
                pipe.hincrby(job_key, "dropped", int(buf.dropped.sum()))
                pipe.hincrby(job_key, "version", 1)
                pipe.execute()
                break
            except redis.WatchError:
                continue
    # After the transaction: bookkeeping that is idempotent by itself.
    meta = store.get_job(job_id)
    if meta is not None:
        samples = int(r.hget(store.k("job", job_id, "tile_samples"), str(tile)) or 0)
        if samples >= meta.plan.spp:
            store.set_tile_state(job_id, tile, "done")
        store.finish_if_complete(job_id)
    return True


def sweep(store: JobStore) -> int:
    """Merge every pass buffer listed as pending; finish jobs whose last merge was interrupted.
    Returns how many passes this sweep merged."""
    merged = 0
    for raw in store.r.smembers(store.k("pending")):
        key = raw.decode()
        # {prefix}:job:{id}:pass:{tile}:{pass}; the prefix may itself hold colons.
        parts = key[len(store.prefix) + 1:].split(":")
        if len(parts) != 5 or parts[0] != "job" or parts[2] != "pass":
            store.r.srem(store.k("pending"), raw)
            continue
        try:
            merged += merge_pass(store, parts[1], int(parts[3]), int(parts[4]))
        except Exception:  # a corrupt buffer must not stop the sweeper
            log.exception("cannot merge %s", key)
    for job_id in store.active_job_ids():
        store.finish_if_complete(job_id)
    return merged


class Sweeper:
    """The service's background merger: ``sweep`` at start and every ``interval`` seconds."""

    def __init__(self, store: JobStore, interval: float):
        self.store = store
        self.interval = interval
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        sweep(self.store)  # carry on from Redis before serving
        self._thread = threading.Thread(target=self._run, name="lucent-sweeper", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                sweep(self.store)
            except redis.RedisError as err:
                log.warning("sweep failed: %s", err)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)


def assemble(store: JobStore, job_id: str) -> tuple[SampleBuffer, int] | None:
    """The frame's merged ``SampleBuffer`` as it stands, and the ``version`` it shows."""
    meta = store.get_job(job_id)
    if meta is None:
        return None
    plan = meta.plan
    frame = SampleBuffer.empty(0, 0, plan.width, plan.height)
    for data in store.tile_buffers(job_id, plan.n_tiles):
        if data is not None:
            frame.add(SampleBuffer.from_bytes(data))
    return frame, meta.version


def frame_image(frame: SampleBuffer) -> np.ndarray:
    """Linear float32 HxWx3 (pixels with no sample yet are black)."""
    return frame.mean()
