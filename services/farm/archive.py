"""A finished job's life after its last merge: its image to the blob store, then its deletion.

- ``archive_done`` (the sweeper, every ``sweep_interval``): each job that became done has its
  image written once to the blob store, the EXR and the PNG at the default exposure exactly as
  ``GET /api/jobs/{id}/image.exr`` / ``.png`` served them from Redis, and then its tile
  accumulations and other tile keys are deleted from Redis (``JobStore.archive_job``). Redis holds
  what is in flight; the job's hash and scene stay there (job records move to a database later,
  issue #20), so the job still lists.
- ``final_image``: what the image routes serve for an archived job: the stored bytes, or for the
  PNG at another exposure or tone map and for ``.npy``, the stored EXR decoded (float32,
  lossless) and encoded again.
- ``delete_finished``: ``DELETE /api/jobs/{id}`` of a done, failed or cancelled job: its keys, and
  its blobs when no other job's image is the same bytes.
- ``expire_finished`` (the sweeper, with ``LUCENT_KEEP_DAYS``): the same for jobs finished longer
  ago than that.

Archiving and deleting are safe against each other and against a second sweeper: ``archive_job``
takes its references on the blobs in the same Redis script that checks the job is still done and
not archived; a blob is deleted only when the script that dropped its last reference says so.
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Callable

import numpy as np

from renderer.film.image_io import decode_exr, encode_exr
from services.farm.blobs import BlobStore, put_content
from services.farm.merge import assemble
from services.farm.store import JobMeta, JobStore

log = logging.getLogger(__name__)

# The image as the routes serve it by default (their query's defaults): what is stored as PNG.
DEFAULT_EXPOSURE = 0.0
DEFAULT_TONEMAP = "clamp"

# Jobs one sweep deletes for retention at most (the rest in the next sweeps).
EXPIRE_BATCH = 100


def encode_image(image: np.ndarray, fmt: str, exposure: float = DEFAULT_EXPOSURE,
                 tonemap: str = DEFAULT_TONEMAP) -> bytes:
    """The frame (h, w, 3 float32) as ``png`` (tone mapped, 8-bit sRGB), ``exr`` or ``npy``."""
    if fmt == "npy":
        out = io.BytesIO()
        np.save(out, image, allow_pickle=False)
        return out.getvalue()
    if fmt == "exr":
        return encode_exr(image)
    from PIL import Image

    from renderer.film.tonemap import to_srgb8

    out = io.BytesIO()
    Image.fromarray(to_srgb8(image, exposure=exposure, tonemap=tonemap)).save(out, format="PNG")
    return out.getvalue()


def archive_job(store: JobStore, blobs: BlobStore, job_id: str) -> bool:
    """Write a done job's image to the blob store and drop its tile keys from Redis. True if this
    call archived it; False if the job is gone, not done, or archived already."""
    assembled = assemble(store, job_id)
    if assembled is None:
        store.archive_job(job_id, {})  # gone: only takes it off the list to archive
        return False
    image = assembled[0].mean()
    data = {"exr": encode_image(image, "exr"), "png": encode_image(image, "png")}
    images = {fmt: put_content(blobs, b) for fmt, b in data.items()}
    if not store.archive_job(job_id, images):
        for key in images.values():  # written for nothing, unless another job's image
            if not store.blob_in_use(key):
                blobs.delete(key)
        return False
    # A job with the same image deleted between our write and our reference removed the blob
    for fmt, key in images.items():
        if not blobs.exists(key):
            blobs.put(key, data[fmt])
    return True


def archive_done(store: JobStore, blobs: BlobStore) -> int:
    """Archive every done job not archived yet; returns how many this call archived."""
    archived = 0
    for job_id in store.jobs_to_archive():
        try:
            archived += archive_job(store, blobs, job_id)
        except OSError:  # a full or missing blob folder: the job stays in Redis, tried again
            log.exception("cannot write the image of job %s to the blob store", job_id)
    return archived


def final_image(blobs: BlobStore, meta: JobMeta, fmt: str, exposure: float,
                tonemap: str) -> bytes | None:
    """An archived job's image as ``encode_image`` makes it, from the blob store; None when the
    job is not archived (its image is in Redis) or its blob is missing."""
    if not meta.images:
        return None
    if fmt == "png" and exposure == DEFAULT_EXPOSURE and tonemap == DEFAULT_TONEMAP:
        return blobs.get(meta.images["png"])
    exr = blobs.get(meta.images["exr"])
    if exr is None:
        return None
    return exr if fmt == "exr" else encode_image(decode_exr(exr), fmt, exposure, tonemap)


def delete_finished(store: JobStore, blobs: BlobStore, job_id: str) -> bool:
    """Delete a done, failed or cancelled job: its Redis keys and the blobs only it used. False
    (nothing deleted) when it is gone or still queued or running."""
    unused = store.delete_job(job_id)
    if unused is None:
        return False
    for key in unused:
        blobs.delete(key)
    return True


def expire_finished(store: JobStore, blobs: BlobStore, keep_days: float,
                    now: float | None = None) -> int:
    """Delete the jobs that finished more than ``keep_days`` ago (``EXPIRE_BATCH`` at most);
    returns how many."""
    now = time.time() if now is None else now
    return sum(delete_finished(store, blobs, job_id)
               for job_id in store.finished_before(now - keep_days * 86400.0, EXPIRE_BATCH))


def chores(store: JobStore, blobs: BlobStore, archive: bool,
           keep_days: float | None) -> list[Callable[[], object]]:
    """What the sweeper does for finished jobs after each sweep: with ``archive``, the done
    ones' images to the blob store; with ``keep_days``, delete those finished longer ago."""
    out: list[Callable[[], object]] = [lambda: archive_done(store, blobs)] if archive else []
    if keep_days is not None:
        out.append(lambda: expire_finished(store, blobs, keep_days))
    return out
