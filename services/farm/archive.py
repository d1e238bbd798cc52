"""Farm state that lasts: job records in SQL, finished jobs' images in the blob store, Redis left
with what is in flight.

A job's life across the three stores:

1. **submitted**: its hash, scene and tile hashes in Redis (``JobStore.create_job``), then its row
   in the database (``Records.create``), then its passes queued. A row always has a Redis job
   behind it until the job is archived, so a row whose job Redis no longer holds was lost there.
2. **in flight**: workers render and merge in Redis only (they never touch the database). Every
   sweep, the service's sweeper copies each job's status, counters and times to its row
   (``Archive.sweep``), so that listing and filtering by status, done in the database, lag Redis by
   at most one ``LUCENT_SWEEP_INTERVAL``; the listing shows the live values of the rows it returns.
3. **finished** (done, failed or cancelled in Redis): the sweeper archives it (``archive``): the
   image as ``image.exr`` and ``image.png`` serve it, the scene, and for a failed or cancelled job
   the merged samples and the list of merged passes (``resume.npz``) go to the blob store; the row
   gets the final counters, the tiles' table and ``archived_at``; then every Redis key of the job is
   deleted. Each step can be repeated: a sweeper that dies mid-way, or a database that does not
   answer, leaves the job in Redis, and a later sweep archives it again from the start.
4. **retried** (failed or cancelled, archived): ``restore`` puts it back in Redis as it stopped
   (the tiles' merged buffers cut from the stored frame, the merged passes), its row running again.
5. **deleted** (``DELETE /api/jobs/{id}`` of a finished job, ``LUCENT_KEEP_DAYS``): row, blobs and
   any Redis keys go. ``LUCENT_MAX_IMAGE_BYTES`` removes the oldest images and keeps their rows.

Two sweepers (two API processes) archive a job once: the archive is claimed in Redis
(``claim_archive``). A job deleted while it is being archived stays deleted: the archive's update
of the row finds no row, and the archive removes the blobs it wrote.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import time
from dataclasses import dataclass

import numpy as np

from renderer.film.buffer import SampleBuffer
from services.farm.blobs import BlobStore, FileBlobStore
from services.farm.images import decode_exr, encode
from services.farm.planner import Plan
from services.farm.records import Archived, JobRecord, Records
from services.farm.settings import Settings
from services.farm.store import FINAL, JobMeta, JobStore

log = logging.getLogger(__name__)

# A claim on archiving one job outlives any archive (seconds: a 4K frame's image takes a few).
ARCHIVE_CLAIM_SECONDS = 600.0
# Jobs archived in one sweep at most: a backlog (an upgrade from a farm that kept every job in
# Redis) is worked off over several sweeps, none of which holds the sweeper long.
ARCHIVES_PER_SWEEP = 20

LOST = ("lost: Redis no longer holds this job's queue and samples (it was restarted without "
        "persistence, or flushed); submit the scene again")


def job_blob(job_id: str, name: str = "") -> str:
    return f"jobs/{job_id}/{name}" if name else f"jobs/{job_id}"


IMAGE_BLOBS = ("image.exr", "image.png", "resume.npz")


@dataclass(frozen=True)
class TileTable:
    """Per tile: state, samples per pixel merged, last error."""

    states: dict[int, str]
    samples: dict[int, int]
    errors: dict[int, str]

    def to_json(self) -> dict:
        return {"state": {str(t): s for t, s in self.states.items()},
                "samples": {str(t): n for t, n in self.samples.items()},
                "error": {str(t): e for t, e in self.errors.items()}}

    @classmethod
    def from_json(cls, d: dict | None) -> TileTable:
        d = d or {}
        return cls({int(t): s for t, s in d.get("state", {}).items()},
                   {int(t): int(n) for t, n in d.get("samples", {}).items()},
                   {int(t): e for t, e in d.get("error", {}).items()})


class Archive:
    """The job records, the blob store and the Redis job store, kept in step."""

    def __init__(self, store: JobStore, records: Records, blobs: BlobStore, settings: Settings):
        self.store = store
        self.records = records
        self.blobs = blobs
        self.settings = settings
        self._synced: dict[str, tuple] = {}
        self._last_round = 0.0

    @classmethod
    def open(cls, store: JobStore, settings: Settings) -> Archive:
        """Connect to the database and migrate it, open the blob store, and give a row to any job
        Redis holds without one (a farm upgraded from keeping everything in Redis)."""
        records = Records(settings.database, settings.database_schema)
        records.migrate()
        archive = cls(store, records, FileBlobStore(settings.blob_root), settings)
        adopted = records.adopt(store.jobs_in_flight())
        if adopted:
            log.warning("%d jobs Redis held had no record: recorded", adopted)
        return archive

    def close(self) -> None:
        self.records.close()

    # --- reading --------------------------------------------------------------------------------
    def job(self, job_id: str) -> tuple[JobMeta, TileTable] | None:
        """The job and its tiles: live from Redis while it is there, else from its record."""
        meta = self.store.get_job(job_id)
        states = self.store.tile_states(job_id) if meta is not None else {}
        if meta is not None and states:  # (no tile states: archived since its hash was read)
            return meta, TileTable(states, self.store.tile_samples(job_id),
                                   self.store.tile_errors(job_id))
        record = self.records.get(job_id)
        if record is None:
            return None
        return record.meta, TileTable.from_json(record.tiles)

    def page(self, status: str | None, offset: int,
             limit: int) -> tuple[list[JobMeta], int]:
        """A page of the job list from the database; the rows of jobs Redis holds show their
        live values (one round trip for the page)."""
        rows, total = self.records.page(status, offset, limit)
        live = self.store.get_jobs([r.meta.id for r in rows if r.archived_at is None])
        return [live.get(r.meta.id, r.meta) for r in rows], total

    def stored_image(self, record: JobRecord, fmt: str, exposure: float,
                     tonemap: str) -> bytes | str:
        """An archived job's image in ``fmt``, or why there is none."""
        job_id = record.meta.id
        if record.image_removed_at is not None:
            return (f"the image of job {job_id} was removed to keep the blob store under "
                    "LUCENT_MAX_IMAGE_BYTES (its record is kept)")
        if fmt == "png" and exposure == 0.0 and tonemap == "clamp":
            data = self.blobs.get(job_blob(job_id, "image.png"))
        else:
            exr = self.blobs.get(job_blob(job_id, "image.exr"))
            data = exr if exr is None or fmt == "exr" else encode(decode_exr(exr), fmt,
                                                                   exposure, tonemap)
        if data is None:
            return f"job {job_id} has no stored image" + (f" ({record.meta.error})"
                                                           if record.meta.error else "")
        return data

    # --- the sweeper's round --------------------------------------------------------------------
    def sweep(self, now: float | None = None) -> int:
        """Copy the state of the jobs in Redis to their rows, archive finished ones, and every
        ``retention_interval`` look for lost jobs and apply the retention settings. Returns how
        many jobs this call archived."""
        now = time.time() if now is None else now
        metas = self.store.jobs_in_flight()
        marks = {m.id: (m.status, m.version, m.started_at, m.finished_at, m.error) for m in metas}
        self.records.sync([m for m in metas if self._synced.get(m.id) != marks[m.id]])
        self._synced = marks
        archived = 0
        for meta in metas:
            if meta.status in FINAL and archived < ARCHIVES_PER_SWEEP:
                archived += self.archive(meta.id)
        if now - self._last_round >= self.settings.retention_interval:
            self._last_round = now
            self.mark_lost()
            self.apply_retention(now)
        return archived

    def archive(self, job_id: str) -> bool:
        """Move a finished job out of Redis (see the module docstring); True if this call did."""
        if not self.store.claim_archive(job_id, ARCHIVE_CLAIM_SECONDS):
            return False  # another sweeper is at it
        try:
            snap = self.store.snapshot(job_id)
            if snap is None or snap.meta.status not in FINAL:
                return False
            meta, merged = snap.meta, snap.merged
            tiles = TileTable(snap.tile_states, snap.tile_samples, snap.tile_errors)
            frame = SampleBuffer.empty(0, 0, meta.plan.width, meta.plan.height)
            for data in snap.tile_buffers:
                if data is not None:
                    frame.add(SampleBuffer.from_bytes(data))
            image = frame.mean()
            blobs = {"image.exr": encode(image, "exr"), "image.png": encode(image, "png")}
            if meta.status != "done" and merged:
                blobs["resume.npz"] = _resume_bytes(frame, merged)
            self.blobs.put(job_blob(job_id, "scene.json"), snap.scene_json)
            size = sum(self.blobs.put(job_blob(job_id, name), data)
                       for name, data in blobs.items())
            samples = frame.count + frame.dropped
            # the passes delivered more than once, and how often (lost workers, crashes)
            redelivered = {m: n for m, n in snap.attempts.items() if n > 1}
            done = Archived({**tiles.to_json(), "redelivered": redelivered}, size,
                            (int(samples.min()), int(samples.max())))
            if not self.records.archive(meta, done):
                self.blobs.delete(job_blob(job_id))  # deleted meanwhile: stays deleted
            self.store.delete_job(job_id)
            return True
        finally:
            self.store.release_archive(job_id)

    def mark_lost(self) -> int:
        """Fail the rows of queued or running jobs that Redis no longer holds."""
        expected = self.records.unarchived_active()
        held = self.store.get_jobs(expected)
        lost = [j for j in expected if j not in held]
        n = self.records.mark_lost(lost, LOST)
        if n:
            log.warning("%d jobs were lost with Redis's state: marked failed", n)
        return n

    def apply_retention(self, now: float) -> None:
        keep_days, cap = self.settings.keep_days, self.settings.max_image_bytes
        if keep_days is not None:
            for job_id in self.records.finished_before(now - keep_days * 86400.0):
                self.remove(job_id)
        if cap is not None:
            for job_id in self.records.images_over(cap):
                for name in IMAGE_BLOBS:
                    self.blobs.delete(job_blob(job_id, name))
                self.records.image_removed(job_id)

    # --- deleting and retrying ------------------------------------------------------------------
    def remove(self, job_id: str) -> None:
        """Delete a finished job: its row, its Redis keys (if not archived yet), its blobs."""
        self.records.delete(job_id)
        self.store.delete_job(job_id)
        self.blobs.delete(job_blob(job_id))

    def restore(self, record: JobRecord) -> list[tuple[int, int]] | str:
        """Put an archived failed or cancelled job back in Redis, running, as it stopped;
        returns its (tile, pass) pairs still to render, or why it cannot be retried."""
        meta, job_id = record.meta, record.meta.id
        scene = self.blobs.get(job_blob(job_id, "scene.json"))
        if scene is None:
            return f"job {job_id} cannot be retried: its scene is not stored ({meta.error})"
        resume = self.blobs.get(job_blob(job_id, "resume.npz"))
        buffers: dict[int, bytes] = {}
        samples: dict[int, int] = {}
        merged: list[str] = []
        if resume is None:  # nothing merged, or the image cap removed it: from the start
            meta = dataclasses.replace(meta, tasks_merged=0, samples_merged=0, dropped=0)
        else:
            frame, merged = _read_resume(resume)
            samples = TileTable.from_json(record.tiles).samples
            for t in {int(m.split(":")[0]) for m in merged}:
                buffers[t] = _crop(frame, meta.plan, t).to_bytes()
        self.store.restore_job(meta, scene, buffers, merged, samples)
        try:
            reopened = self.records.reopen(job_id)
        except Exception:
            self.store.delete_job(job_id)
            raise
        if not reopened:  # retried by another request meanwhile
            self.store.delete_job(job_id)
            return f"job {job_id} is no longer failed or cancelled"
        for name in IMAGE_BLOBS:
            self.blobs.delete(job_blob(job_id, name))
        return self.store.unmerged(job_id, meta.plan)


def _resume_bytes(frame: SampleBuffer, merged: list[str]) -> bytes:
    pairs = np.array([[int(x) for x in m.split(":")] for m in merged], np.int64)
    out = io.BytesIO()
    np.savez(out, frame=np.frombuffer(frame.to_bytes(), np.uint8), merged=pairs)
    return out.getvalue()


def _read_resume(data: bytes) -> tuple[SampleBuffer, list[str]]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        frame = SampleBuffer.from_bytes(z["frame"].tobytes())
        merged = [f"{t}:{p}" for t, p in z["merged"].tolist()]
    return frame, merged


def _crop(frame: SampleBuffer, plan: Plan, tile: int) -> SampleBuffer:
    """A tile's merged buffer, cut from the frame (tiles do not overlap: exactly its sums)."""
    x0, y0, w, h = plan.tile_rect(tile)
    window = (slice(y0, y0 + h), slice(x0, x0 + w))
    return SampleBuffer(x0, y0, frame.sum[window].copy(), frame.sum_sq[window].copy(),
                        frame.count[window].copy(), frame.dropped[window].copy())
