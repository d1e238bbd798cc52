"""A finished job's life after its last merge: its image to the blob store, then its deletion.

- ``archive_done`` (the sweeper, every ``sweep_interval``): each job that became done has its
  image written once to the blob store, the EXR and the PNG at the default exposure exactly as
  ``GET /api/jobs/{id}/image.exr`` / ``.png`` served them from Redis, its last state and its
  tiles' summary written to its record (``services.farm.records``), and then every key of it is
  deleted from Redis: Redis holds what is in flight, the record the rest.
- ``keep_records`` (the sweeper, every sweep): the records of the jobs Redis holds brought up to
  date; jobs queued or running whose state Redis lost are marked failed.
- ``frame_exr``: a done frame's EXR; with the scene's ``film.aovs``, the multi-layer EXR of
  ``renderer.film.image_io.encode_exr_layers`` (the AOV pass traced here, once, by whoever
  archives the job or serves a done one not archived).
- ``final_image``: what the image routes serve for an archived job: the stored bytes, or for the
  PNG at another exposure or tone map and for ``.npy``, the stored EXR decoded (float32,
  lossless) and encoded again.
- ``delete_finished``: ``DELETE /api/jobs/{id}`` of a done, failed or cancelled job: its keys, its
  record, and its blobs when no other job's image is the same bytes.
- ``expire_finished`` (the sweeper, with ``LUCENT_KEEP_DAYS``): the same for jobs finished longer
  ago than that.
- ``park_finished`` (the sweeper, ``LUCENT_PARK_AFTER`` after they ended): failed and cancelled
  jobs out of Redis too, their tiles' state as one blob and their record; ``unpark_job`` brings
  one back for a retry.
- ``cap_images`` (the sweeper, with ``LUCENT_MAX_IMAGE_BYTES``): the images of the oldest finished
  jobs removed until the rest fit; their records stay.

Archiving and deleting are safe against each other and against a second sweeper: the record is
written only if it still exists (a deletion meanwhile: the archive removes what it wrote), the
deletion reads the blob keys from the row it deletes, and a blob is deleted only when no record
names it.
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Callable

import numpy as np

from renderer.film.buffer import SampleBuffer
from renderer.film.image_io import decode_exr, encode_exr, encode_exr_layers
from services.farm.blobs import BlobStore, asset_reader, put_content
from services.farm.frames import PatchError, apply_patch
from services.farm.merge import assemble
from services.farm.records import LOST_AFTER, Records
from services.farm.store import ACTIVE, JobMeta, JobSnapshot, JobStore

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


# Primary rays a pixel for the albedo, normal and depth layers (as ``lucent render``)
AOV_SPP = 8


def frame_layers(store: JobStore, blobs: BlobStore, meta: JobMeta, frame: int,
                 buffer: SampleBuffer, extra: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The AOV layers that frame ``frame``'s scene asks for (``film.aovs``), and those of
    ``extra``; {} when none: the scene loaded and compiled here (its assets from the blob store),
    the albedo, normal and depth traced with ``AOV_SPP`` rays a pixel, variance and spp from the
    merged ``buffer``. A scene that no longer loads (the workers rendered it, so only a lost
    asset) logs and gives {}: the image is still archived."""
    from renderer.film.aov import frame_aovs
    from renderer.scene import load_scene
    from renderer.scene.compile import CompileError, compile_scene
    from renderer.scene.load import SceneError

    scene_json = store.get_scene(meta.id)
    if scene_json is None:
        return {}
    try:
        if meta.plan.frames > 1:
            patches = store.get_frames(meta.id)
            if patches is None:
                return {}
            scene_json = apply_patch(scene_json, patches[frame])
        film = scene_json.get("film") if isinstance(scene_json, dict) else None
        if not extra and (not isinstance(film, dict) or not film.get("aovs")):
            return {}
        scene = load_scene(scene_json, assets=asset_reader(blobs))
        names = list(dict.fromkeys([*scene.film.aovs, *extra]))
        if not names:
            return {}
        compiled = compile_scene(scene)
    except (SceneError, CompileError, PatchError, KeyError):
        log.exception("job %s: the AOV layers of frame %d cannot be traced", meta.id, frame)
        return {}
    return frame_aovs(compiled, buffer, names, spp=AOV_SPP)


def frame_exr(store: JobStore, blobs: BlobStore, meta: JobMeta, frame: int,
              buffer: SampleBuffer) -> tuple[np.ndarray, bytes]:
    """A done frame's image and its EXR, with the layers of ``frame_layers`` when it has any.
    A job with ``denoise``: the image denoised by Open Image Denoise (``renderer.film.denoise``,
    guided by the albedo and normal AOVs, traced for it), the undenoised one kept as the EXR's
    ``noisy`` layer; without ``pyoidn`` here (the API refuses such a job, but the archiver may
    run elsewhere) it logs and the image stays undenoised, without a ``noisy`` layer."""
    from renderer.film.denoise import denoise, oidn_available

    image = buffer.mean()
    clean = meta.denoise and oidn_available()
    if meta.denoise and not clean:
        log.error("job %s asks for denoise but pyoidn is not installed here: its image is "
                  "archived undenoised", meta.id)
    layers = frame_layers(store, blobs, meta, frame, buffer,
                          ("albedo", "normal") if clean else ())
    if clean and "albedo" in layers:
        noisy = image
        image = denoise(noisy, layers["albedo"], layers["normal"])
        aovs = frame_scene_aovs(store, meta, frame)
        layers = {"noisy": noisy, **{n: v for n, v in layers.items() if n in aovs}}
    if layers:
        return image, encode_exr_layers(image, layers)
    return image, encode_image(image, "exr")


def frame_scene_aovs(store: JobStore, meta: JobMeta, frame: int) -> list[str]:
    """The ``film.aovs`` of frame ``frame``'s scene, as stored (validated when submitted)."""
    scene_json = store.get_scene(meta.id)
    if meta.plan.frames > 1 and scene_json is not None:
        patches = store.get_frames(meta.id)
        scene_json = apply_patch(scene_json, patches[frame]) if patches else None
    film = scene_json.get("film") if isinstance(scene_json, dict) else None
    aovs = film.get("aovs") if isinstance(film, dict) else None
    return list(aovs) if isinstance(aovs, list) else []


def archive_job(store: JobStore, records: Records, blobs: BlobStore, job_id: str) -> bool:
    """Write a done job's image to the blob store and its last state to its record, then delete
    its keys from Redis. True if this call archived it; False if the job is gone from Redis or
    not done, or its record was deleted meanwhile (what was written for it is removed)."""
    meta = store.get_job(job_id)
    assembled = assemble(store, job_id) if meta is not None and meta.status == "done" else None
    if meta is None or assembled is None:
        store.forget_archive(job_id)  # gone or retried: only takes it off the list to archive
        return False
    # Each frame's image (a job of frames: the first is the job's image, the record's
    # ``tiles`` lists them all)
    frames_data = []
    for f in range(meta.plan.frames):
        frame = assembled if f == 0 else assemble(store, job_id, f)
        if frame is None:  # deleted meanwhile
            store.forget_archive(job_id)
            return False
        image, exr = frame_exr(store, blobs, meta, f, frame[0])
        frames_data.append({"exr": exr, "png": encode_image(image, "png")})
    frame_images = [{fmt: put_content(blobs, b) for fmt, b in data.items()}
                    for data in frames_data]
    images = frame_images[0]
    tiles = store.tiles_final(job_id, meta.plan.n_tiles)
    if meta.plan.frames > 1:
        tiles["frame_images"] = frame_images
    size = sum(len(b) for data in frames_data for b in data.values())
    if not records.archive(meta, images, tiles, size):
        record = records.get(job_id)
        if record is not None and record.images:
            # Archived already: by another sweeper at the same moment (lucent up's two API
            # processes), or by one that died before deleting the job from Redis. Its record
            # stands (Records.archive writes once); the job leaves Redis as it would have left
            # it. (Its images are that record's: the same content, the same keys.)
            store.delete_job(job_id, ("done",))
            return False
        # deleted meanwhile
        for key in {k for fi in frame_images for k in fi.values()}:
            if not records.blob_in_use(key):  # written for nothing, unless another job's
                blobs.delete(key)
        store.forget_archive(job_id)
        return False
    # A job with the same image deleted between our write and our record removed the blob
    for data, keys in zip(frames_data, frame_images, strict=True):
        for fmt, key in keys.items():
            if not blobs.exists(key):
                blobs.put(key, data[fmt])
    store.delete_job(job_id, ("done",))
    return True


def archive_done(store: JobStore, records: Records, blobs: BlobStore) -> int:
    """Archive every done job not archived yet; returns how many this call archived."""
    archived = 0
    for job_id in store.jobs_to_archive():
        try:
            archived += archive_job(store, records, blobs, job_id)
        except OSError:  # a full or missing blob folder: the job stays in Redis, tried again
            log.exception("cannot write the image of job %s to the blob store", job_id)
    return archived


def park_job(store: JobStore, records: Records, blobs: BlobStore, job_id: str) -> bool:
    """Move a failed or cancelled job out of Redis: its tiles' accumulations, samples, errors,
    merged passes and scene as one blob (``JobSnapshot``), its last state to its record, then
    its keys deleted. A retry brings it back (``unpark_job``). True if this call parked it."""
    snap = store.snapshot(job_id)
    if snap is None or snap.meta.status not in ("failed", "cancelled"):
        return False
    state = put_content(blobs, snap.to_bytes())
    tiles = {"states": {str(t): s for t, s in snap.tile_states.items()},
             "samples": [snap.tile_samples.get(t, 0) for t in range(snap.meta.plan.n_tiles)],
             "errors": {str(t): e for t, e in snap.tile_errors.items()}}
    if not records.park(snap.meta, state, tiles):  # deleted meanwhile
        if not records.blob_in_use(state):
            blobs.delete(state)
        return False
    if not store.delete_job(job_id, (snap.meta.status,)):
        # retried (or changed) since the snapshot: it stays in Redis, its record follows it
        records.unpark(job_id)
        if not records.blob_in_use(state):
            blobs.delete(state)
        return False
    return True


def park_finished(store: JobStore, records: Records, blobs: BlobStore, after: float,
                  now: float | None = None) -> int:
    """Park the failed and cancelled jobs that finished more than ``after`` seconds ago
    (``EXPIRE_BATCH`` at most); returns how many."""
    now = time.time() if now is None else now
    parked = 0
    for job_id in store.finished_in_redis(now - after, EXPIRE_BATCH):
        try:
            parked += park_job(store, records, blobs, job_id)
        except OSError:
            log.exception("cannot write the state of job %s to the blob store", job_id)
    return parked


def unpark_job(store: JobStore, records: Records, blobs: BlobStore, meta: JobMeta) -> bool:
    """Bring a parked job back into Redis as it was parked (for a retry); False when it is not
    parked or its blob is missing."""
    if not meta.parked:
        return False
    data = blobs.get(meta.parked)
    if data is None:
        return False
    store.restore_job(JobSnapshot.from_bytes(data))
    state = records.unpark(meta.id)
    if state and not records.blob_in_use(state):
        blobs.delete(state)
    return True


def assemble_parked(blobs: BlobStore, meta: JobMeta,
                    frame_index: int = 0) -> tuple[SampleBuffer, int] | None:
    """A parked job's frame as it stood when it was parked, and its ``version``."""
    data = blobs.get(meta.parked) if meta.parked else None
    if data is None:
        return None
    snap = JobSnapshot.from_bytes(data)
    plan = snap.meta.plan
    frame = SampleBuffer.empty(0, 0, plan.width, plan.height)
    for buf in snap.tile_buffers[frame_index * plan.tiles_per_frame:
                                 (frame_index + 1) * plan.tiles_per_frame]:
        if buf is not None:
            frame.add(SampleBuffer.from_bytes(buf))
    return frame, snap.meta.version


def keep_records(store: JobStore, records: Records, now: float | None = None,
                 adopt: bool = False) -> int:
    """Bring the records of the jobs Redis holds up to date (``Records.sync``); move the jobs
    that a farm from before the records archived (their hash holds the blob keys) to the records
    alone (``adopt``: at start-up, with rows made for the jobs that have none); fail the records
    of jobs queued or running whose state Redis lost. Returns the rows written."""
    now = time.time() if now is None else now
    metas = store.jobs_in_flight()
    written = records.sync(metas, adopt)
    for meta in metas:
        if meta.images:
            store.delete_job(meta.id, ("done",))
    held = {m.id for m in metas}
    lost = [j for j in records.active_ids(now - LOST_AFTER) if j not in held]
    # read again: a job submitted or retried since the first read is not lost
    lost = [j for j in lost if store.get_status(j) is None]
    return written + records.mark_lost(
        lost, "Redis lost this job's in-flight state (it restarted without its data)")


def final_image(blobs: BlobStore, meta: JobMeta, fmt: str, exposure: float,
                tonemap: str, frame: int = 0) -> bytes | None:
    """An archived job's image (of frame ``frame``) as ``encode_image`` makes it, from the blob
    store; None when the job is not archived (its image is in Redis) or its blob is missing."""
    if not meta.images:
        return None
    images = meta.tiles_final.get("frame_images", [meta.images])[frame] if frame else meta.images
    if fmt == "png" and exposure == DEFAULT_EXPOSURE and tonemap == DEFAULT_TONEMAP:
        return blobs.get(images["png"])
    exr = blobs.get(images["exr"])
    if exr is None:
        return None
    return exr if fmt == "exr" else encode_image(decode_exr(exr), fmt, exposure, tonemap)


def delete_finished(store: JobStore, records: Records, blobs: BlobStore, job_id: str) -> bool:
    """Delete a done, failed or cancelled job: its Redis keys, its record and the blobs no
    other job's image is. False (nothing deleted) when it is unknown or still queued or running."""
    status = store.get_status(job_id)
    if status is not None and not store.delete_job(job_id):
        # Queued or running; or gone from Redis since it was read: archived (or parked) in
        # between by the sweeper, and then its record decides, as below
        status = store.get_status(job_id)
        if status is not None:
            return False
    if status is None:
        record = records.get(job_id)
        if record is None or record.status in ACTIVE:
            return False  # unknown, or lost by Redis and not marked yet: the sweeper will
    images = records.delete(job_id)
    if images is None and status is None:
        return False
    for key in (images or {}).values():
        if not records.blob_in_use(key):
            blobs.delete(key)
    return True


def cap_images(records: Records, blobs: BlobStore, cap: int) -> int:
    """Remove the images of the oldest finished jobs until the rest fit in ``cap`` bytes (their
    records stay; their image routes answer 410); returns how many."""
    removed = 0
    for job_id in records.images_over(cap)[:EXPIRE_BATCH]:
        keys = records.remove_image(job_id)
        for key in keys.values():
            if not records.blob_in_use(key):
                blobs.delete(key)
        removed += bool(keys)
    return removed


def expire_finished(store: JobStore, records: Records, blobs: BlobStore, keep_days: float,
                    now: float | None = None) -> int:
    """Delete the jobs that finished more than ``keep_days`` ago (``EXPIRE_BATCH`` at most);
    returns how many."""
    now = time.time() if now is None else now
    return sum(delete_finished(store, records, blobs, job_id)
               for job_id in records.finished_before(now - keep_days * 86400.0, EXPIRE_BATCH))


def chores(store: JobStore, records: Records, blobs: BlobStore, archive: bool,
           keep_days: float | None, max_image_bytes: int | None = None,
           park_after: float | None = None) -> list[Callable[[], object]]:
    """What the sweeper does after each sweep: the job records up to date; with ``archive``, the
    done jobs' images to the blob store and their keys out of Redis; with ``keep_days``, delete
    the jobs finished longer ago."""
    out: list[Callable[[], object]] = [lambda: keep_records(store, records)]
    if archive:
        out.append(lambda: archive_done(store, records, blobs))
    if keep_days is not None:
        out.append(lambda: expire_finished(store, records, blobs, keep_days))
    if max_image_bytes is not None:
        out.append(lambda: cap_images(records, blobs, max_image_bytes))
    if park_after is not None:
        out.append(lambda: park_finished(store, records, blobs, park_after))
    return out
