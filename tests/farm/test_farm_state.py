"""Farm state that lasts (issue #20): job records in SQL, Redis left with what is in flight; the
database or Redis going away.

Against a real Redis and the configured database: SQLite in the test's data folder, or the
PostgreSQL of ``DATABASE_URL`` (a schema per test: tests/farm/conftest.py ``farm_state``).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import os
import socket
import socketserver
import threading
import time
import uuid

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import inspect

from services.api.main import create_app
from services.farm.archive import cap_images, keep_records
from services.farm.blobs import FileBlobStore, put_content
from services.farm.planner import Plan
from services.farm.records import LOST_AFTER, Records
from services.farm.settings import Settings
from services.farm.store import JobMeta
from services.launcher import EmbeddedRedis, start_worker, terminate
from tests.farm.conftest import (
    WORKER_START_TIMEOUT,
    drop_farm_state,
    farm_state,
    records_of,
)


def _meta(created_at: float, status: str = "done", name: str = "") -> JobMeta:
    finished = created_at + 1 if status in ("done", "failed", "cancelled") else None
    return dataclasses.replace(
        JobMeta.new(uuid.uuid4().hex, name, 0, Plan(32, 24, 16, 16, 8), {}, created_at),
        status=status, started_at=created_at, finished_at=finished)


def _archived(records: Records, job_id: str) -> bool:
    record = records.get(job_id)
    return record is not None and bool(record.images)


def _merge_noisy_pass(store, job_id: str, plan: Plan, tile: int, pass_index: int, rng,
                      scale: float = 0.5):
    """Merge pass ``pass_index`` of ``tile``: 8 samples a pixel drawn from Γ(2, ``scale``) per
    channel (noise the adaptive rule estimates); returns its buffer."""
    from renderer.film.buffer import SampleBuffer

    buf = SampleBuffer.empty(*plan.tile_rect(tile))
    x = rng.gamma(2.0, scale, size=(8,) + buf.sum.shape)
    buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), 8
    store.put_pass(job_id, tile, pass_index, buf.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, tile, pass_index)
    return buf


# --- job records in SQL --------------------------------------------------------------------------


def test_migration_at_start_up_is_idempotent(settings):
    """The schema is upgraded when the API starts, and starting again (or migrating again by
    hand) changes nothing and keeps the rows."""
    with TestClient(create_app(settings)) as c:
        assert c.get("/api/jobs").json()["count"] == 0
    records = records_of(settings)
    assert records.revision() == "0007"
    records.create(_meta(time.time()))
    records.migrate()
    with TestClient(create_app(settings)) as c:
        assert c.get("/api/jobs").json()["count"] == 1
    assert records.revision() == "0007"
    indexes = {i["name"] for i in inspect(records.engine).get_indexes("jobs")}
    assert {"jobs_created_at", "jobs_status_created_at", "jobs_finished_at", "jobs_image_exr",
            "jobs_image_png", "jobs_request_key"} <= indexes


def test_a_request_key_is_one_jobs(settings):
    """A job's row keeps the Idempotency-Key it was submitted with (scoped to its submitter) and
    its request's digest, unique: a second job's row with the same key is not written, and the
    first job is the answer (two identical requests at the same moment make one job). Another
    submitter's same key is another request; a deleted row frees its key."""
    from services.farm.records import Submission, request_key

    records = records_of(settings)
    first, second = _meta(time.time(), "queued"), _meta(time.time(), "queued")
    alices = Submission(request_key("alice", "k-1"), "digest-1")
    assert records.create(first, alices) is None
    prior = records.create(second, alices)
    assert prior is not None and (prior[0].id, prior[1]) == (first.id, "digest-1")
    assert records.get(second.id) is None
    assert records.by_request(alices.key)[0].id == first.id
    assert records.by_request(request_key(None, "k-1")) is None
    assert records.create(second, Submission(request_key("bob", "k-1"), "digest-1")) is None
    assert records.get(second.id) is not None
    records.delete(first.id)
    assert records.by_request(alices.key) is None


def test_the_counts_migration_counts_the_jobs_already_there(tmp_path):
    """A database at the first migration, with jobs in it, upgraded: the counts by status
    (kept by triggers from then on) start from the jobs it has."""
    records = Records(f"sqlite:///{tmp_path}/old.db")
    records.migrate("0001")
    t0 = time.time()
    for status in ("done", "done", "failed", "running"):
        records.create(_meta(t0, status))
    records.migrate()
    assert records.revision() == "0007"
    assert records.count_by_status() == {"queued": 0, "running": 1, "done": 2, "failed": 1,
                                         "cancelled": 0}
    first = records.page("done")[0][0]
    assert records.sync([dataclasses.replace(first, status="failed")]) == 1
    records.delete(records.page("running")[0][0].id)
    assert records.count_by_status() == {"queued": 0, "running": 0, "done": 1, "failed": 2,
                                         "cancelled": 0}
    assert records.page()[1] == 3 and records.page("failed")[1] == 2


def test_a_parked_target_job_is_listed_and_shown_with_its_target_and_error(settings, store):
    """A cancelled job with a target error, parked out of Redis: its record, listed (a page,
    which reads no tiles' summary) and read whole, gives its target, bias and the expected
    error its merges had reached. Seen failing before the record kept them as columns
    (migration 0007): a parked job's summary holds neither, so both gave the target as None."""
    import numpy as np

    from services.farm.archive import park_job

    records = records_of(settings)
    plan = Plan(32, 16, 64, 16, 8)  # 2 tiles x 8 passes of 8
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.02,
                     expected_bias=0.003)
    records.create(store.get_job(job_id))
    rng = np.random.default_rng(3)
    for t in range(plan.n_tiles):
        _merge_noisy_pass(store, job_id, plan, t, 0, rng)
    expected = store.get_job(job_id).expected_error
    assert expected is not None
    assert store.cancel_job(job_id)
    assert park_job(store, records, FileBlobStore(settings.blob_path), job_id)
    assert store.get_job(job_id) is None
    for meta in (next(m for m in records.page()[0] if m.id == job_id), records.get(job_id)):
        assert meta.status == "cancelled" and meta.parked
        assert (meta.target_error, meta.expected_bias) == (0.02, 0.003)
        assert meta.expected_error == pytest.approx(expected, rel=1e-12)


def test_the_errors_migration_takes_an_archived_jobs_errors_from_its_tiles_summary(settings):
    """A database at 0006 whose archived jobs keep their target, expected error, bias and
    denoise only in their tiles' summary (JSON a listing's page does not read), upgraded: a
    page lists each archived job with them, as its record's detail gives them; a job whose
    summary has none lists none (on SQLite, and on PostgreSQL with ``DATABASE_URL``). Seen
    failing with the upgrade's copy left out: the page listed the target job's target and error
    as None and its denoise as False."""
    import json

    from sqlalchemy import update

    from services.farm.records import jobs

    records = Records(settings.database, settings.database_schema)
    records.migrate("0006")
    t0 = time.time()
    target, plain = _meta(t0), _meta(t0 + 1)
    kept = {"target_error": 0.05, "expected_error": 0.031, "expected_bias": 0.004,
            "denoise": True}
    for meta, final in ((target, kept), (plain, {})):
        records.create(meta)
        with records.engine.begin() as conn:  # archived as 0006 archived it
            conn.execute(update(jobs).where(jobs.c.id == meta.id).values(
                tiles=json.dumps({"samples": [16] * 4, "errors": {}, **final}),
                archived_at=t0 + 2))
    records.migrate()
    assert records.revision() == "0007"
    page = {m.id: m for m in records.page()[0]}
    listed = page[target.id]
    assert listed.tiles_final == {}  # (the page did not read the summary)
    assert (listed.target_error, listed.expected_error, listed.expected_bias,
            listed.denoise) == (0.05, 0.031, 0.004, True)
    detail = records.get(target.id)
    assert (detail.target_error, detail.expected_error, detail.expected_bias,
            detail.denoise) == (0.05, 0.031, 0.004, True)
    other = page[plain.id]
    assert (other.target_error, other.expected_error, other.expected_bias,
            other.denoise) == (None, None, 0.0, False)


def test_a_plans_pass_growth_lasts_in_the_records_redis_and_a_snapshot(tmp_path, store):
    """A job's pass growth decides which samples each pass index renders, so it is kept
    wherever the plan is: the job's hash, its record, a parked job's snapshot. Each written
    before the growth was a field (a database at 0004, a hash or snapshot without it) reads as
    growth 1, the rule those jobs were planned with."""
    import json

    from services.farm.store import JobSnapshot

    records = Records(f"sqlite:///{tmp_path}/old.db")
    records.migrate("0004")
    old = _meta(time.time(), "done")
    records.create(old)
    records.migrate()
    assert records.get(old.id).plan.pass_growth == 1
    grown = dataclasses.replace(_meta(time.time()),
                                plan=Plan(64, 64, 64, 32, 8, 64, pass_growth=2))
    records.create(grown)
    assert records.get(grown.id).plan == grown.plan
    assert records.get(grown.id).plan.n_passes == 3  # 8, 16, 40

    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, grown.plan, b"{}", {}, time.time())
    assert store.get_job(job_id).plan == grown.plan
    store.r.hdel(store.job_key(job_id), "pass_growth")  # a job stored before the field
    assert store.get_job(job_id).plan.pass_growth == 1

    snap = JobSnapshot(grown, b"{}", {}, {}, {}, [], [None] * grown.plan.n_tiles)
    assert JobSnapshot.from_bytes(snap.to_bytes()).meta.plan == grown.plan
    line, _, rest = snap.to_bytes().partition(b"\n")
    head = json.loads(line)
    head["meta"]["plan"] = head["meta"]["plan"][:7]  # a snapshot from before the field
    before = JobSnapshot.from_bytes(json.dumps(head).encode() + b"\n" + rest)
    assert before.meta.plan.pass_growth == 1


def test_a_parked_target_job_comes_back_with_its_target_and_error_sums(store):
    """A job with render.target_error keeps, beside its tiles, the target and the sums of its
    tiles' error summaries (the frame's scale and expected error come from them). Parked and
    restored (a retry), it has the same target, the same sums and the same per-tile summaries
    that its merges kept: each is a function of the tile's merged buffer; and the sums of its
    tiles' first looks, which is not, carried by the snapshot. Without them the
    retry would send every unmerged pass (not one chain a tile) and the frame's estimate would
    count only the tiles merged after it."""
    import numpy as np

    from services.farm.store import JobSnapshot

    rng = np.random.default_rng(7)
    plan = Plan(32, 16, 64, 16, 8)  # 2 tiles x 8 passes of 8
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.02,
                     expected_bias=0.003)
    for t, passes in ((0, 2), (1, 1)):
        for p in range(passes):
            _merge_noisy_pass(store, job_id, plan, t, p, rng)
    before = store.get_job(job_id)
    kept = store.r.hgetall(store.k("job", job_id, "tile_err"))
    assert before.target_error == 0.02 and before.expected_error is not None and len(kept) == 2
    assert before.expected_bias == 0.003

    snap = store.snapshot(job_id)
    assert JobSnapshot.from_bytes(snap.to_bytes()).meta.target_error == 0.02
    assert JobSnapshot.from_bytes(snap.to_bytes()).meta.expected_bias == 0.003
    assert store.delete_job(job_id, statuses=("queued", "running"))
    store.restore_job(JobSnapshot.from_bytes(snap.to_bytes()))
    after = store.get_job(job_id)
    assert after.target_error == 0.02 and after.expected_bias == 0.003
    # (and the sums of the tiles' first looks and pilots, which the merged buffers no longer
    # tell)
    assert before.look_pixels == 32 * 16 and before.first_look_bound is not None
    assert before.pilot_pixels == 32 * 16 and before.pilot_error is not None
    for name in ("err_sum", "weight_sum", "err_pixels", "look_sum", "look_sq_sum",
                 "look_pixels", "pilot_sum", "pilot_pixels"):
        assert getattr(after, name) == pytest.approx(getattr(before, name), rel=1e-12), name
    assert after.expected_error == pytest.approx(before.expected_error, rel=1e-12)
    assert after.first_look_bound == pytest.approx(before.first_look_bound, rel=1e-12)
    restored = store.r.hgetall(store.k("job", job_id, "tile_err"))
    assert restored.keys() == kept.keys()
    for t, summary in kept.items():
        assert [float(x) for x in restored[t].split()] == pytest.approx(
            [float(x) for x in summary.split()], rel=1e-12)

    # A job without a target restores without one, with its summaries (its estimate) too
    plain = uuid.uuid4().hex
    store.create_job(plain, "", 0, plan, b"{}", {}, time.time())
    snap = store.snapshot(plain)
    assert store.delete_job(plain, statuses=("queued",))
    store.restore_job(JobSnapshot.from_bytes(snap.to_bytes()))
    assert store.get_job(plain).target_error is None
    assert not store.r.exists(store.k("job", plain, "tile_err"))
    for t in (0, 1):
        _merge_noisy_pass(store, plain, plan, t, 0, rng)
    before = store.get_job(plain)
    snap = store.snapshot(plain)
    assert before.expected_error is not None
    assert store.delete_job(plain, statuses=("queued", "running"))
    store.restore_job(JobSnapshot.from_bytes(snap.to_bytes()))
    after = store.get_job(plain)
    assert after.target_error is None
    assert after.expected_error == pytest.approx(before.expected_error, rel=1e-12)
    assert store.tile_estimates(plain).keys() == {0, 1}


@pytest.mark.parametrize("target", [0.02, None])
def test_a_job_reports_each_tiles_estimate_while_in_redis_and_archived(store, target):
    """Each tile's estimated error (the status answer's ``tile_states[].expected_error``) is the
    mean of its pixels' error terms in its merged buffer, in the job's view while Redis holds it
    and in the tiles' summary its record keeps once archived, with a target or without; over
    the frame's pixels they make the job's estimate. A job nothing was merged into has
    none."""
    import numpy as np

    from renderer.film.adaptive import error_terms

    rng = np.random.default_rng(3)
    plan = Plan(40, 16, 64, 16, 8)  # 3 tiles (16, 16 and 8 px wide) x 8 passes of 8
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=target)
    merged = {}
    for t in (0, 2):  # (tile 1 merges nothing: no estimate)
        for p in range(2):
            buf = _merge_noisy_pass(store, job_id, plan, t, p, rng, 0.5 + t)
            merged[t] = merged[t] + buf if t in merged else buf
    want = {t: float(error_terms(b).mean()) for t, b in merged.items()}
    view = store.job_view(job_id)
    assert view is not None and view[5].keys() == {0, 2}
    for t, e in want.items():
        assert view[5][t] == pytest.approx(e, rel=1e-12)
    final = store.tiles_final(job_id, plan.n_tiles)
    assert {int(t): e for t, e in final["estimates"].items()} == view[5]
    assert view[0].expected_error is None and "expected_error" not in final  # tile 1: none
    assert ("target_error" in final) == (target is not None)
    # tile 1's first pass: every pixel has an estimate, the job's is their pixels' mean
    merged[1] = _merge_noisy_pass(store, job_id, plan, 1, 0, rng)
    frame = np.concatenate([error_terms(merged[t]).ravel() for t in range(3)])
    assert store.get_job(job_id).expected_error == pytest.approx(frame.mean(), rel=1e-12)
    assert store.tiles_final(job_id, plan.n_tiles)["expected_error"] == pytest.approx(
        frame.mean(), rel=1e-12)

    nothing = uuid.uuid4().hex
    store.create_job(nothing, "", 0, plan, b"{}", {}, time.time(), target_error=target)
    assert store.job_view(nothing)[5] == {} and "estimates" not in store.tiles_final(nothing, 3)


def test_a_tile_summary_of_the_previous_rule_is_taken_back_out(store):
    """A job with a target running across the upgrade: a tile whose stored summary is the
    previous rule's three numbers (Σ e, Σ w, pixels; no squares of the terms), in the job's
    sums, merges again under the new rule: the job's sums are then the new summary's, the old
    ones taken back out and the squares added (none was before)."""
    import numpy as np

    from renderer.film.adaptive import tile_summary
    from renderer.film.buffer import SampleBuffer

    rng = np.random.default_rng(3)
    plan = Plan(16, 16, 64, 16, 8)  # one tile, passes of 8
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.02)

    def one_pass(p: int) -> None:
        _merge_noisy_pass(store, job_id, plan, 0, p, rng)

    one_pass(0)
    job_key = store.k("job", job_id)
    # what a worker of the previous rule left: its summary of three, without the squares, and
    # the job's sums of it
    store.r.hset(store.k("job", job_id, "tile_err"), "0", "0.5 12.0 256.0")
    store.r.hset(job_key, mapping={"err_sum": 0.5, "weight_sum": 12.0, "err_pixels": 256})
    store.r.hdel(job_key, "err_sq_sum")
    one_pass(1)
    merged = SampleBuffer.from_bytes(store.tile_buffer(job_id, 0))
    e, weight, pixels, e_sq = tile_summary(merged)
    after = store.get_job(job_id)
    assert (after.err_sum, after.weight_sum, after.err_pixels, after.err_sq_sum) == pytest.approx(
        (e, weight, pixels, e_sq), rel=1e-9)


def test_listing_pages_and_filters_in_the_database(client, settings):
    """Jobs Redis does not hold (archived ones) are listed from their records: newest first,
    paged by offset and limit, filtered by status, with the total that matches."""
    records = records_of(settings)
    t0 = time.time() - 1000
    metas = [_meta(t0 + i, "done" if i % 3 else "failed", f"job {i}") for i in range(25)]
    records.create_many(metas)
    newest_first = [m.id for m in reversed(metas)]
    page = client.get("/api/jobs", params={"offset": 5, "limit": 10}).json()
    assert page["count"] == 25
    assert [j["id"] for j in page["data"]] == newest_first[5:15]
    failed = client.get("/api/jobs", params={"status": "failed", "limit": 500}).json()
    assert failed["count"] == 9
    assert [j["id"] for j in failed["data"]] == [m.id for m in reversed(metas)
                                                  if m.status == "failed"]
    assert client.get(f"/api/jobs/{metas[4].id}").json()["name"] == "job 4"
    text = client.get("/metrics").text
    assert 'lucent_jobs{status="done"} 16' in text and 'lucent_jobs{status="failed"} 9' in text


def test_the_image_cap_removes_the_oldest_images_and_keeps_the_records(client, settings):
    """Over ``LUCENT_MAX_IMAGE_BYTES`` the oldest finished jobs' images go (blobs no other job
    names deleted); their records stay, and their image routes answer 410 saying why."""
    records = records_of(settings)
    blobs = FileBlobStore(settings.blob_path)
    t0 = time.time() - 1000
    metas = [_meta(t0 + i, "done", f"job {i}") for i in range(3)]
    records.create_many(metas)
    for i, meta in enumerate(metas):
        images = {fmt: put_content(blobs, f"{fmt} of job {i}".encode() * 100)
                  for fmt in ("exr", "png")}
        assert records.archive(meta, images, {"samples": [], "errors": {}}, 1000)
    assert cap_images(records, blobs, 1500) == 2  # 3000 bytes: the two oldest go
    assert cap_images(records, blobs, 1500) == 0
    assert len([p for p in settings.blob_path.rglob("*") if p.is_file()]) == 2
    for meta in metas[:2]:
        r = client.get(f"/api/jobs/{meta.id}/image.png")
        assert r.status_code == 410 and "LUCENT_MAX_IMAGE_BYTES" in r.json()["detail"]
        assert client.get(f"/api/jobs/{meta.id}").json()["status"] == "done"
    assert client.get(f"/api/jobs/{metas[2].id}/image.png").content == b"png of job 2" * 100
    assert client.get("/api/jobs").json()["count"] == 3


def test_the_image_cap_removes_every_frame_of_a_job_of_frames(client, settings):
    """A job of frames over the cap loses every frame's image, not only the first: each
    frame's blobs are deleted, and a frame's route answers 410 as the job's image does."""
    records = records_of(settings)
    blobs = FileBlobStore(settings.blob_path)
    base = _meta(time.time() - 100, "done", "a sequence")
    meta = dataclasses.replace(base, plan=dataclasses.replace(base.plan, frames=3))
    records.create(meta)
    frame_images = [{fmt: put_content(blobs, f"{fmt} of frame {f}".encode() * 100)
                     for fmt in ("exr", "png")} for f in range(3)]
    assert records.archive(meta, frame_images[0], {"samples": [], "errors": {},
                                                   "frame_images": frame_images}, 6000)
    assert client.get(f"/api/jobs/{meta.id}/frames/2/image.png").content == b"png of frame 2" * 100
    assert cap_images(records, blobs, 1000) == 1
    assert not [p for p in settings.blob_path.rglob("*") if p.is_file()]
    for url in (f"/api/jobs/{meta.id}/image.png", f"/api/jobs/{meta.id}/frames/2/image.png"):
        assert client.get(url).status_code == 410, url
    assert client.get(f"/api/jobs/{meta.id}").json()["status"] == "done"


def test_a_named_token_is_recorded_as_the_submitter(redis_base_url, tmp_path, tiny_scene):
    prefix = f"lucent-test-{uuid.uuid4().hex[:10]}"
    settings = Settings(redis_url=redis_base_url, key_prefix=prefix,
                        api_tokens="alice:a-s3cret,bob:b-s3cret",
                        **farm_state(prefix, tmp_path / "data"))
    try:
        with TestClient(create_app(settings)) as c:
            assert c.get("/api/jobs").status_code == 401
            assert c.get("/api/jobs", headers={"Authorization": "Bearer bob"}).status_code == 401
            r = c.post("/api/jobs", json={"scene": tiny_scene},
                       headers={"Authorization": "Bearer b-s3cret"})
            assert r.status_code == 201, r.text
            assert r.json()["submitter"] == "bob"
            listed = c.get("/api/jobs", headers={"Authorization": "Bearer a-s3cret"}).json()
            assert [j["submitter"] for j in listed["data"]] == ["bob"]
        assert records_of(settings).get(r.json()["id"]).submitter == "bob"
    finally:
        drop_farm_state(settings)


def test_a_job_whose_state_redis_lost_is_marked_failed(settings, store):
    """A record queued or running whose job Redis no longer holds (Redis restarted without its
    data) is failed by the sweeper, saying why; one just submitted is left alone."""
    records = records_of(settings)
    lost = _meta(time.time() - LOST_AFTER - 5, "running")
    young = _meta(time.time(), "queued")
    records.create_many([lost, young])
    keep_records(store, records)
    after = records.get(lost.id)
    assert after.status == "failed" and "Redis lost" in after.error
    assert records.get(young.id).status == "queued"


def test_history_survives_a_redis_restart(tmp_path, tiny_scene, wait_until):
    """Redis restarted empty (no persistence) once every job finished: nothing of the history
    is lost, as none of it was in Redis any more."""
    server = EmbeddedRedis().start()
    prefix = f"lucent-test-{uuid.uuid4().hex[:10]}"
    settings = Settings(redis_url=server.url, key_prefix=prefix, sweep_interval=0.2,
                        **farm_state(prefix, tmp_path / "data"))
    worker = start_worker(server.url, concurrency=1, name=f"{prefix}@%h",
                          extra_env={"LUCENT_KEY_PREFIX": prefix, "LUCENT_API_TOKEN": ""},
                          log=open(tmp_path / "worker.log", "w"))
    try:
        records = records_of(settings)
        with TestClient(create_app(settings)) as api:
            ids = [api.post("/api/jobs", json={"scene": tiny_scene, "name": f"n{i}"}).json()["id"]
                   for i in range(3)]
            for job_id in ids:
                wait_until(lambda j=job_id: _archived(records, j), WORKER_START_TIMEOUT,
                           "the job archived")
            pngs = {j: api.get(f"/api/jobs/{j}/image.png").content for j in ids}
        terminate(worker, 30.0)
        port = server.port
        server.stop()
        server = EmbeddedRedis(port=port).start()  # empty
        with TestClient(create_app(settings)) as api:
            listed = api.get("/api/jobs").json()
            assert listed["count"] == 3
            assert {(j["id"], j["status"]) for j in listed["data"]} == {(j, "done") for j in ids}
            assert {j: api.get(f"/api/jobs/{j}/image.png").content for j in ids} == pngs
    finally:
        terminate(worker, 30.0)
        server.stop()
        drop_farm_state(settings)


# --- the database going away mid-job -------------------------------------------------------------

def _pump(src: socket.socket, dst: socket.socket) -> None:
    with contextlib.suppress(OSError):
        while data := src.recv(65536):
            dst.sendall(data)
    for s in (src, dst):
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_RDWR)


class _Forward(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        server: _Proxy = self.server  # type: ignore[assignment]
        if not server.up:
            return  # refused: the connection is closed at once
        upstream = socket.create_connection(server.target)
        server.conns += [self.request, upstream]
        threading.Thread(target=_pump, args=(upstream, self.request), daemon=True).start()
        _pump(self.request, upstream)


class _Proxy(socketserver.ThreadingTCPServer):
    """A TCP proxy in front of PostgreSQL that can go away, as a stopped server does (every
    connection closed, new ones closed at once), and come back on the same port."""

    daemon_threads = True

    def __init__(self, host: str, port: int):
        self.target = (host, port)
        self.up = True
        self.conns: list[socket.socket] = []
        super().__init__(("127.0.0.1", 0), _Forward)
        self.port = self.server_address[1]
        threading.Thread(target=self.serve_forever, daemon=True).start()

    def cut(self) -> None:
        self.up = False
        for s in self.conns:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
        self.conns.clear()

    def heal(self) -> None:
        self.up = True



def test_the_database_going_away_mid_job_is_503_and_loses_no_pass(farm, tmp_path, wait_until,
                                                                 tiny_scene):
    """The job database stops answering mid-job (PostgreSQL: its connections cut and refused;
    SQLite: its folder gone): the routes that need it answer 503, the job goes on in Redis (its
    status is still served), and once the database is back it is archived whole."""
    url = os.environ.get("DATABASE_URL")
    proxy = None
    state = farm_state(farm.settings.key_prefix + "-db", tmp_path / "data")
    if url:
        from sqlalchemy.engine import make_url

        u = make_url(url)
        proxy = _Proxy(u.host or "127.0.0.1", u.port or 5432)
        state["database_url"] = u.set(host="127.0.0.1", port=proxy.port).render_as_string(
            hide_password=False)
    settings = farm.settings.model_copy(update={**state, "blob_dir": tmp_path / "blobs",
                                                "sweep_interval": 0.2})
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 48, "height": 32}
    scene["render"]["spp"] = 64
    try:
        with TestClient(create_app(settings)) as api:
            job_id = api.post("/api/jobs", json={"scene": scene, "tile_size": 16,
                                                 "spp_per_pass": 4, "max_spp_per_pass": 4}
                              ).json()["id"]
            wait_until(lambda: api.get(f"/api/jobs/{job_id}").json()["tasks_merged"] > 0, 120,
                       "passes merging")
            if proxy is not None:
                proxy.cut()
            else:
                (tmp_path / "data").rename(tmp_path / "away")
            for method, path in [("GET", "/api/jobs"), ("GET", "/metrics"),
                                 ("POST", "/api/jobs")]:
                r = api.request(method, path, json={"scene": tiny_scene})
                assert r.status_code == 503, (method, path, r.text)
                assert r.json()["detail"].startswith("the farm's job database"), r.text
            assert api.get("/readyz").status_code == 503
            # Redis holds the job meanwhile: it is served, and it finishes
            store = farm.store()
            wait_until(lambda: store.get_status(job_id) == "done", 120, "the job done in Redis")
            assert api.get(f"/api/jobs/{job_id}").json()["status"] == "done"
            time.sleep(1.0)  # sweeps that fail to archive it
            assert store.get_status(job_id) == "done"
            if proxy is not None:
                proxy.heal()
            else:
                (tmp_path / "away").rename(tmp_path / "data")
            records = Records(settings.database, settings.database_schema)
            wait_until(lambda: _archived(records, job_id), 60, "the job archived")
            meta = records.get(job_id)
            assert meta.status == "done" and meta.tasks_merged == meta.plan.n_tasks
            assert meta.samples_merged + meta.dropped == 48 * 32 * 64  # no pass lost
            # (the archive writes the record first and then deletes the job's keys: a CI run
            # once read the record between the two)
            wait_until(lambda: store.get_status(job_id) is None, 30, "the job out of Redis")
            assert api.get(f"/api/jobs/{job_id}/image.png").status_code == 200
    finally:
        if proxy is not None:
            proxy.shutdown()
            proxy.server_close()
        drop_farm_state(settings.model_copy(update={"database_url": url}) if url else settings)


@pytest.mark.parametrize("noise, asked_again", [(0.8, True), (1e-6, False)])
def test_converged_tiles_are_asked_again_once_no_tile_renders(store, noise, asked_again):
    """A tile of a job with a target error that found nothing to add waits, converged, with its
    later passes unsent: the frame's scale, which the other tiles' merges move, may give it
    samples later. Once no tile renders or waits for a pass (the last chain ended),
    settle_converged asks it again under the frame's scale then: a noisy tile (8 samples a
    pixel of σ 0.8, relMSE ~0.08 against a target of 0.02) is queued again at its next pass and
    begins as any pass does; a flat one ends, its passes counted as merged, and the job is done.
    While another tile's chain goes on, nothing is decided."""
    import numpy as np

    from renderer.film.buffer import SampleBuffer
    from services.farm.targets import settle_converged

    rng = np.random.default_rng(11)
    # 2 tiles x passes of 8, 8, 16, 32, which the plan's order lists largest first: a tile's
    # next pass is its lowest unmerged one, not the first unmerged in that order
    plan = Plan(32, 16, 64, 16, 8, 32)
    assert plan.order()[2] == (0, 3)

    def merge(t: int, p: int, sigma: float) -> None:
        buf = SampleBuffer.empty(*plan.tile_rect(t))
        x = 1.0 + sigma * rng.standard_normal(size=(8,) + buf.sum.shape)
        buf.sum[:] = x.sum(axis=0)
        buf.sum_sq[:] = (x * x).sum(axis=0)
        buf.count[:] = 8
        store.put_pass(job_id, t, p, buf.to_bytes(), ttl=60)
        assert store.merge_pass_buffer(job_id, t, p)

    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.02)
    sent: list[tuple[int, int]] = []

    def send(todo, meta) -> None:
        assert meta.id == job_id
        sent.extend(todo)

    merge(0, 0, noise)
    store.set_tile_state(job_id, 0, "converged")  # as the worker that found nothing to add
    merge(1, 0, 0.3)  # tile 1 goes on: its next pass is queued
    assert settle_converged(store, send, job_id) == [] and sent == []
    assert store.tile_states(job_id)[0] == "converged"
    assert not store.is_merged(job_id, 0, 1)
    # The stall rule's re-send of a converged tile's next pass begins like any: the tile runs
    # (until that pass, finding nothing to add either, leaves it converged again)
    store.add_attempt(job_id, 0, 1, running=True)
    assert store.tile_states(job_id)[0] == "running"
    store.set_tile_state(job_id, 0, "converged")

    for p in range(1, plan.n_passes):  # tile 1's chain ends with its last pass
        merge(1, p, 0.3)
    again = settle_converged(store, send, job_id)
    job = store.get_job(job_id)
    if asked_again:
        assert again == sent == [(0, 1)]
        assert store.tile_states(job_id)[0] == "queued" and job.status in ("queued", "running")
        assert not store.is_merged(job_id, 0, 1)
    else:
        assert again == sent == []
        assert job.status == "done" and job.tasks_merged == plan.n_tasks
        assert store.tile_states(job_id) == {0: "done", 1: "done"}
        assert store.is_merged(job_id, 0, plan.n_passes - 1)


# The first-look tests' job: 2 tiles of 16 px, passes of 8
LOOK_PLAN = Plan(32, 16, 256, 16, 8)


def look_tile(t: int, x):
    """Tile ``t`` of ``LOOK_PLAN``'s buffer of the grey samples ``x`` (n, 16, 16, 3)."""
    from renderer.film.buffer import SampleBuffer

    buf = SampleBuffer.empty(*LOOK_PLAN.tile_rect(t))
    buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), len(x)
    return buf


def first_looks(rng):
    """Two first looks (``FIRST_LOOK`` samples a pixel) of ``LOOK_PLAN``'s tiles: tile 0 of even
    noise (relative variance 1), tile 1 four times as noisy; and tile 0's own first-look
    bound."""
    from renderer.film.adaptive import FIRST_LOOK, error_terms, first_look_bound

    shape = (FIRST_LOOK, 16, 16, 3)
    even = look_tile(0, rng.exponential(1.0, shape))
    noisy = look_tile(1, rng.gamma(0.25, 4.0, shape))
    terms = error_terms(even).ravel()
    return even, noisy, first_look_bound(terms.sum(), float((terms * terms).sum()), terms.size)


def test_a_target_jobs_first_look_takes_the_frames_bound_once_every_tile_has_one(store):
    """After a tile's first look (``FIRST_LOOK`` samples a pixel) the farm's rule stops as the
    local loop's does, on the first look's bound (the error terms' mean plus ``FIRST_LOOK_Z``
    standard errors): the tile's own before every tile has merged its first look, then the
    frame's, from the job's sums (``JobMeta.first_look_bound``, the same as the bound of every
    pixel's terms together). A tile of even noise beside one four times as noisy: alone, the
    even tile stops at a target its bound reaches; once the other has merged, the frame's bound
    does not reach it, and the even tile takes the rest of the pilot; at a target the frame's
    bound reaches, both stop."""
    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, PILOT, STOP_SLACK, error_terms
    from services.farm.targets import adaptive_counts

    rng = np.random.default_rng(9)
    plan = LOOK_PLAN
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.5)
    even, noisy, own = first_looks(rng)
    terms = error_terms(even).ravel()
    loose = 1.02 * own / (AIM * (1 + STOP_SLACK))
    store.put_pass(job_id, 0, 0, even.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, 0, 0)
    meta = store.get_job(job_id)
    assert meta.first_look_bound is None  # (tile 1 has not merged: the tile's own decides)
    assert not adaptive_counts(store, meta, 0, loose, 8).any()
    store.put_pass(job_id, 1, 0, noisy.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, 1, 0)
    meta = store.get_job(job_id)
    both = np.concatenate([terms, error_terms(noisy).ravel()])
    assert meta.first_look_bound == pytest.approx(
        both.mean() + 2.0 * both.std() / np.sqrt(both.size), rel=1e-9)
    assert meta.first_look_bound > 1.5 * own
    assert (adaptive_counts(store, meta, 0, loose, 8) == PILOT - FIRST_LOOK).all()
    # a target the frame's bound is within: both stop
    far = 1.02 * meta.first_look_bound / (AIM * (1 + STOP_SLACK))
    assert not adaptive_counts(store, meta, 0, far, 8).any()
    assert not adaptive_counts(store, meta, 1, far, 8).any()


def test_a_tile_stopped_on_its_own_first_look_is_asked_again_on_the_frames(store):
    """The frame's first-look bound is the bound of every tile's first look, each tile's first
    merged pass (``JobMeta.first_look_bound``), not of the job's sums after later passes: a tile
    of even noise stops on its own bound before the other tile has merged; the other, four
    times as noisy at its first look, then merges a pass of 200 samples a pixel, which takes
    the job's sums (and a bound on them) within the aim. Once no tile renders, the first tile
    is asked again (``settle_converged``) on the frames' first look, which is not within the
    aim, and is queued for the rest of its pilot, as the local loop, whose first look saw the
    whole frame, would have gone on."""
    import numpy as np

    from renderer.film.adaptive import (
        AIM,
        STOP_SLACK,
        aim_reached,
        error_terms,
        first_look_bound,
    )
    from services.farm.targets import adaptive_counts, settle_converged

    rng = np.random.default_rng(21)
    job_id = uuid.uuid4().hex
    even, noisy, own = first_looks(rng)
    terms = error_terms(even).ravel()
    loose = float(1.02 * own / (AIM * (1 + STOP_SLACK)))
    plan = LOOK_PLAN
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=loose)
    store.put_pass(job_id, 0, 0, even.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, 0, 0)
    assert not adaptive_counts(store, store.get_job(job_id), 0, loose, 8).any()
    store.set_tile_state(job_id, 0, "converged")  # as the worker that found nothing to add
    store.put_pass(job_id, 1, 0, noisy.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, 1, 0)
    look = np.concatenate([terms, error_terms(noisy).ravel()])
    want = first_look_bound(look.sum(), float((look * look).sum()), look.size)
    assert not aim_reached(want, loose)
    assert store.get_job(job_id).first_look_bound == pytest.approx(want, rel=1e-9)
    store.put_pass(job_id, 1, 1, look_tile(1, 1.0 + 0.01 * rng.standard_normal(
        (200, 16, 16, 3))).to_bytes(), ttl=60)
    assert store.merge_pass_buffer(job_id, 1, 1)
    meta = store.get_job(job_id)
    assert meta.first_look_bound == pytest.approx(want, rel=1e-9)  # the first looks' still
    # (on the job's sums now the bound would be within the aim: tile 0 would stay stopped)
    assert aim_reached(first_look_bound(meta.err_sum, meta.err_sq_sum, meta.err_pixels), loose)
    assert not adaptive_counts(store, meta, 1, loose, 8).any()
    store.set_tile_state(job_id, 1, "converged")
    sent: list[tuple[int, int]] = []
    assert settle_converged(store, lambda todo, m: sent.extend(todo), job_id) == [(0, 1)]
    assert sent == [(0, 1)] and store.tile_states(job_id)[0] == "queued"
    assert (adaptive_counts(store, store.get_job(job_id), 0, loose, 8) > 0).all()


def test_a_target_jobs_tiles_end_their_pilot_on_the_frames_estimate_there(store):
    """The end of a tile's pilot (``PILOT`` samples every pixel) waits for the frame's estimate
    there, the sums of every tile's error terms at the merge that ended its pilot
    (``JobMeta.pilot_error``), and takes one count a pixel from it, as the local loop's first
    round after the frame's pilot, whatever the job's running estimate has become since: tile 0
    ends its pilot first and waits, converged; the merge that ends tile 1's completes the sums
    (``FRAME_LOOKED``, as did the one that completed the first looks, and no other) and
    ``wake_converged`` queues tile 0 at once; tile 1 then merges 200 samples a pixel, which
    take the job's running estimate within the aim, and tile 0 still takes its even count.
    Seen failing with the running estimate in the rule, and with the pilot sums added at every
    merge."""
    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, PILOT, aim_reached, error_terms
    from services.farm.store import FRAME_LOOKED
    from services.farm.targets import adaptive_counts, wake_converged

    rng = np.random.default_rng(31)
    job_id = uuid.uuid4().hex
    # each tile's first look and the rest of its pilot, of even noise
    looks = [look_tile(t, rng.exponential(1.0, (FIRST_LOOK, 16, 16, 3))) for t in (0, 1)]
    rests = [look_tile(t, rng.exponential(1.0, (PILOT - FIRST_LOOK, 16, 16, 3))) for t in (0, 1)]
    pilots = []
    for t, (look, rest) in enumerate(zip(looks, rests, strict=True)):
        both = look_tile(t, np.zeros((0, 16, 16, 3)))
        both.add(look)
        both.add(rest)
        pilots.append(both)
    e = float(np.concatenate([error_terms(b).ravel() for b in pilots]).mean())
    target = e / (1.4 * AIM)  # the frame's pilot estimate 1.4x the aim: 12 samples a pixel
    store.create_job(job_id, "", 0, LOOK_PLAN, b"{}", {}, time.time(), target_error=target)
    flags = []
    for t, p, buf in ((0, 0, looks[0]), (0, 1, rests[0]), (1, 0, looks[1]), (1, 1, rests[1])):
        store.put_pass(job_id, t, p, buf.to_bytes(), ttl=60)
        flags.append(store.merge_pass_buffer(job_id, t, p))
        if (t, p) == (0, 1):
            meta = store.get_job(job_id)
            assert meta.pilot_error is None
            assert not adaptive_counts(store, meta, 0, target, 8).any()  # it waits
            store.set_tile_state(job_id, 0, "converged")
    assert [bool(f & FRAME_LOOKED) for f in flags] == [False, False, True, True]
    meta = store.get_job(job_id)
    assert meta.pilot_error == pytest.approx(e, rel=1e-9)
    sent: list[tuple[int, int]] = []
    assert wake_converged(store, lambda todo, m: sent.extend(todo), job_id) == [(0, 2)]
    assert sent == [(0, 2)] and store.tile_states(job_id)[0] == "queued"
    np.testing.assert_array_equal(adaptive_counts(store, meta, 0, target, 16), 12 - PILOT)
    store.put_pass(job_id, 1, 2, look_tile(1, 1.0 + 0.01 * rng.standard_normal(
        (200, 16, 16, 3))).to_bytes(), ttl=60)
    assert not store.merge_pass_buffer(job_id, 1, 2) & FRAME_LOOKED
    meta = store.get_job(job_id)
    assert aim_reached(meta.expected_error, target)  # the running estimate: within the aim
    assert meta.pilot_error == pytest.approx(e, rel=1e-9)  # the pilot's: still 1.4x
    np.testing.assert_array_equal(adaptive_counts(store, meta, 0, target, 16), 12 - PILOT)


def _waiting_at_the_end_of_its_pilot(store, rng):
    """A target job of ``LOOK_PLAN`` whose tiles have ended their pilots (passes 0 and 1
    merged), its frame's estimate there 1.4× the aim (``JobMeta.pilot_error``), and tile 0
    converged with its next pass, 2, unmerged: it stopped to wait for that estimate, which the
    rule now gives samples. Returns the job's id and target."""
    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, PILOT, error_terms

    job_id = uuid.uuid4().hex
    passes = {(t, p): look_tile(t, rng.exponential(1.0, (n, 16, 16, 3)))
              for t in (0, 1) for p, n in ((0, FIRST_LOOK), (1, PILOT - FIRST_LOOK))}
    terms = []
    for t in (0, 1):
        pilot = look_tile(t, np.zeros((0, 16, 16, 3)))
        pilot.add(passes[t, 0])
        pilot.add(passes[t, 1])
        terms.append(error_terms(pilot).ravel())
    target = float(np.concatenate(terms).mean()) / (1.4 * AIM)
    store.create_job(job_id, "", 0, LOOK_PLAN, b"{}", {}, time.time(), target_error=target)
    for (t, p), buf in passes.items():
        store.put_pass(job_id, t, p, buf.to_bytes(), ttl=60)
        store.merge_pass_buffer(job_id, t, p)
    store.set_tile_state(job_id, 0, "converged")
    assert store.get_job(job_id).pilot_error is not None
    return job_id, target


@contextlib.contextmanager
def _moved_on_after_the_read(store, job_id: str, tiles, rng):
    """``store.chain_view`` that, after its read, merges pass 2 of each of ``tiles`` (4 more
    samples a pixel) and leaves the tile converged, as a tile that was sent the pass by another
    caller, rendered it and found nothing more: a merge that lands between a caller's read of
    the tiles and what it does on it."""
    view = store.chain_view

    def read_then_move_on(*args, **kwargs):
        seen = view(*args, **kwargs)
        for t in tiles:
            store.put_pass(job_id, t, 2, look_tile(t, rng.exponential(1.0, (4, 16, 16, 3)))
                           .to_bytes(), ttl=60)
            assert store.merge_pass_buffer(job_id, t, 2)
            store.set_tile_state(job_id, t, "converged")
        return seen

    store.chain_view = read_then_move_on
    try:
        yield
    finally:
        del store.chain_view


def test_a_converged_tile_is_asked_again_once_and_only_at_the_pass_it_waits_at(store):
    """A converged tile asked again is queued and its pass sent only while it is still
    converged at that pass (``JobStore.requeue_converged``, one step). Two wakes at once send
    its pass once. And a wake whose view of the tile is a moment old, a merge having moved the
    tile on since (another wake sent its pass 2, which merged, and the tile converged again at
    3), sends nothing and leaves it converged, for the caller that moved it to ask: sending the
    merged pass 2 (a duplicate, dropped) and marking the tile queued left it waiting with
    nothing in flight until the stall rule, 30 s (caustic floor jobs at 0.1 on an embedded farm
    of two workers, about one in six). Seen failing with the tile marked queued and its pass
    sent whatever it had become (the two reads and the mark apart): two sends, and (0, 2)
    sent a second time with the tile left queued."""
    import numpy as np

    from services.farm.targets import _ask_again, settle_converged, wake_converged

    rng = np.random.default_rng(37)
    job_id, _ = _waiting_at_the_end_of_its_pilot(store, rng)
    meta = store.get_job(job_id)
    sent: list[tuple[int, int]] = []

    def send(todo, m):
        sent.extend(todo)

    # two wakes that both read tile 0 converged at pass 2: the first sends it, the second not
    assert _ask_again(store, send, meta, {0: 2}) == ([(0, 2)], 0)
    assert _ask_again(store, send, meta, {0: 2}) == ([], 1)
    assert sent == [(0, 2)] and store.tile_states(job_id)[0] == "queued"
    assert store.requeue_converged(job_id, 0, 2) is False  # queued: not converged

    # A wake that reads the tile converged at pass 2; then, before it acts, pass 2 renders and
    # merges (sent by another wake) and the tile converges again at pass 3
    job_id, _ = _waiting_at_the_end_of_its_pilot(store, rng)
    sent.clear()
    with _moved_on_after_the_read(store, job_id, (0,), rng):
        assert wake_converged(store, send, job_id) == []
    assert sent == [] and store.tile_states(job_id)[0] == "converged"
    assert store.requeue_converged(job_id, 0, 2) is False  # pass 2: merged
    # the tile as it is now: converged at pass 3, which the rule still gives samples
    assert wake_converged(store, send, job_id) == [(0, 3)] == sent
    assert store.tile_states(job_id)[0] == "queued"

    # The job's end (settle_converged: every tile converged) read a moment before both tiles
    # moved on: it sends nothing, and does not end the job on that old view (their ends do)
    job_id, _ = _waiting_at_the_end_of_its_pilot(store, rng)
    store.set_tile_state(job_id, 1, "converged")
    sent.clear()
    with _moved_on_after_the_read(store, job_id, (0, 1), rng):
        assert settle_converged(store, send, job_id) == []
    assert sent == [] and store.get_status(job_id) in ("queued", "running")
    assert set(store.tile_states(job_id).values()) == {"converged"}


def test_chain_view_reads_a_tiles_state_and_next_pass_together(store):
    """``JobStore.chain_view``: what ``unmerged`` and ``tile_states`` give, the job's and one
    frame's, read in one MULTI/EXEC."""
    from services.farm.planner import Plan

    plan = Plan(32, 16, 64, 16, 16, frames=2)
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.1,
                     frames_json=b"[[], []]")
    for t, p in ((0, 0), (0, 1), (1, 0), (3, 0)):
        store.skip_passes(job_id, t, p, p + 1)
    store.set_tile_state(job_id, 2, "converged")
    assert store.chain_view(job_id, plan) == (store.unmerged(job_id, plan),
                                              store.tile_states(job_id))
    for frame in (0, 1):
        tiles = list(plan.frame_tiles(frame))
        assert store.chain_view(job_id, plan, frame) == (
            store.unmerged(job_id, plan, frame), store.tile_states(job_id, tiles))
    assert (0, 1) not in store.chain_view(job_id, plan, 0)[0]
    assert store.chain_view(job_id, plan, 1)[1][2] == "converged"


def test_a_target_jobs_pixel_that_drops_every_sample_does_not_hold_its_frame_back(store):
    """A pixel whose every sample is dropped as non-finite (its count stays 0) ends its pilot
    with the samples drawn, not kept: its tile's pilot ends, the frame's estimates at the end of
    the pilot and of the job (``pilot_error``, ``expected_error``) become known, the pixel adds
    nothing to them, and past the pilot it takes no more samples while the others take the
    even round. Before, its tile never ended its pilot: every tile waited at the end of its own
    for a frame estimate that never came, the job knew no error, and it ended at the pilot's 8
    samples a pixel whatever the target. Seen failing with the pilot's end on kept samples."""
    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, PILOT, error_terms
    from services.farm.store import FRAME_LOOKED
    from services.farm.targets import adaptive_counts

    rng = np.random.default_rng(37)
    job_id = uuid.uuid4().hex
    dead = (3, 5)  # a pixel of tile 1

    def tile(t: int, n: int):
        buf = look_tile(t, rng.exponential(1.0, (n, 16, 16, 3)))
        if t == 1:
            buf.sum[dead], buf.sum_sq[dead], buf.count[dead], buf.dropped[dead] = 0.0, 0.0, 0, n
        return buf

    passes = {(t, p): tile(t, n) for t in (0, 1)
              for p, n in ((0, FIRST_LOOK), (1, PILOT - FIRST_LOOK))}
    pilots = [look_tile(t, np.zeros((0, 16, 16, 3))).add(passes[t, 0]).add(passes[t, 1])
              for t in (0, 1)]
    e = float(np.concatenate([error_terms(b).ravel() for b in pilots]).mean())
    target = e / (1.4 * AIM)  # the frame's pilot estimate 1.4x the aim: 12 samples a pixel
    store.create_job(job_id, "", 0, LOOK_PLAN, b"{}", {}, time.time(), target_error=target)
    flags = []
    for (t, p), buf in passes.items():
        if (t, p) == (1, 1):
            # the rest of the pilot: the dead pixel takes it again, the others their rest
            want = adaptive_counts(store, store.get_job(job_id), 1, target, 8)
            assert want[dead] == PILOT and (np.delete(want.ravel(), 3 * 16 + 5)
                                             == PILOT - FIRST_LOOK).all()
        store.put_pass(job_id, t, p, buf.to_bytes(), ttl=60)
        flags.append(store.merge_pass_buffer(job_id, t, p))
    assert bool(flags[-1] & FRAME_LOOKED)
    meta = store.get_job(job_id)
    assert meta.pilot_error == pytest.approx(e, rel=1e-9)
    assert meta.expected_error == pytest.approx(e, rel=1e-9)
    counts = adaptive_counts(store, meta, 1, target, 16)
    assert counts[dead] == 0
    assert (np.delete(counts.ravel(), 3 * 16 + 5) == 12 - PILOT).all()
    np.testing.assert_array_equal(adaptive_counts(store, meta, 0, target, 16), 12 - PILOT)


def test_a_target_job_of_frames_samples_each_frame_to_the_target_on_its_own(store, settings,
                                                                          monkeypatch):
    """A job of two frames (a tile each) with a target error: frame 0 nearly noiseless, frame 1
    noisy. Each frame keeps its own error, first-look and pilot sums (``FRAME_SUMS``,
    ``JobMeta.for_frame``), and each tile's rule reads its frame's: frame 0 stops at the end of
    its pilot while frame 1 takes the even round its own estimate asks for (1.4x the aim: 12
    samples a pixel). The frames' pooled estimate is within the aim, and on it both stopped,
    frame 1 above its target (a job of the Cornell box and the glass sphere at 0.03 ended them at
    0.16-0.25x and 1.22-1.24x). A merge that completes one frame's look or pilot says so
    (``FRAME_LOOKED``); a snapshot keeps the frames' sums; the job's answer gives each frame's
    estimate, and its progress is theirs. The frames' sums are in a hash of their own, kept
    only by a target job. Seen failing with the pooled sums in the rule."""
    import dataclasses

    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, PILOT, error_terms, noise_target
    from services.api.routes.jobs import job_detail, list_jobs
    from services.farm.store import FRAME_LOOKED, JobSnapshot
    from services.farm.targets import adaptive_counts

    rng = np.random.default_rng(41)
    plan = Plan(16, 16, 256, 16, 8, 0, 2)  # 2 frames of one 16x16 tile, passes of 8
    job_id = uuid.uuid4().hex

    def samples(t: int, n: int):
        from renderer.film.buffer import SampleBuffer

        x = (1.0 + 0.02 * rng.standard_normal((n, 16, 16, 3)) if t == 0
             else rng.exponential(1.0, (n, 16, 16, 3)))
        buf = SampleBuffer.empty(*plan.tile_rect(t))
        buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), n
        return buf

    passes = {(t, p): samples(t, n) for t in (0, 1)
              for p, n in ((0, FIRST_LOOK), (1, PILOT - FIRST_LOOK))}
    e = [float(error_terms(passes[t, 0] + passes[t, 1]).mean()) for t in (0, 1)]
    target = e[1] / (1.4 * AIM)
    assert (e[0] + e[1]) / 2 < AIM * target  # (pooled, the frames are within the aim)
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=target,
                     expected_bias=0.001)
    flags = []
    for (t, p), buf in passes.items():
        store.put_pass(job_id, t, p, buf.to_bytes(), ttl=60)
        flags.append(bool(store.merge_pass_buffer(job_id, t, p) & FRAME_LOOKED))
    assert flags == [True, True, True, True]
    meta = store.get_job(job_id)
    for f in (0, 1):
        assert store.frame_meta(meta, f).pilot_error == pytest.approx(e[f], rel=1e-9)
        assert store.frame_meta(meta, f).expected_error == pytest.approx(e[f], rel=1e-9)
        assert store.frame_meta(meta, f).first_look_bound is not None
    # (in a hash of their own: the job's, which every pass reads whole, holds none of them)
    assert not [k for k in store.r.hgetall(store.job_key(job_id)) if b":" in k]
    assert meta.pilot_error == pytest.approx((e[0] + e[1]) / 2, rel=1e-9)
    assert not adaptive_counts(store, meta, 0, target, 16).any()
    np.testing.assert_array_equal(adaptive_counts(store, meta, 1, target, 16), 12 - PILOT)
    # The merge that completed frame 1's sums wakes frame 1's converged tiles, not every one
    from services.farm import targets

    for t in (0, 1):
        store.set_tile_state(job_id, t, "converged")
    asked: list[int] = []
    real = targets.adaptive_counts
    monkeypatch.setattr(targets, "adaptive_counts",
                        lambda st, m, t, *a: asked.append(t) or real(st, m, t, *a))
    sent: list[tuple[int, int]] = []
    assert targets.wake_converged(store, lambda todo, m: sent.extend(todo), job_id,
                                  of_tile=1) == [(1, 2)]
    assert asked == [1] and sent == [(1, 2)]
    # ... and frame 0, its tile converged within its own aim, settles while frame 1's tile runs:
    # the job as a whole would wait for it (as a job of one frame does)
    assert targets.settle_converged(store, lambda todo, m: sent.extend(todo), job_id) == []
    assert store.tile_states(job_id) == {0: "converged", 1: "queued"}
    assert targets.settle_converged(store, lambda todo, m: sent.extend(todo), job_id, 0) == []
    assert store.tile_states(job_id) == {0: "done", 1: "queued"}
    assert store.is_merged(job_id, 0, plan.n_passes - 1) and store.get_job(job_id).status != "done"
    # (a job of frames stored before frames kept their own sums: pooled, as it was)
    assert store.frame_meta(dataclasses.replace(meta, frame_sums=False), 1).pilot_error == \
        meta.pilot_error

    detail = job_detail(meta, store.tile_states(job_id), {}, {}, {},
                        store.tile_estimates(job_id))
    assert [f.expected_error for f in detail.frame_progress] == pytest.approx(
        [e[0] + 0.001, e[1] + 0.001], rel=1e-9)
    # its progress: the samples each frame needs to its share of the target (as if even), the
    # frame within it none more; pooled, it would be min(1, share / the frames' mean)
    share = noise_target(target, 0.001)
    needs = (max(1.0, e[0] / share) + max(1.0, e[1] / share)) / 2
    assert detail.progress == pytest.approx(1 / needs, rel=1e-9)
    assert detail.progress < min(1.0, share / meta.expected_error)
    # ... and the job listing (what the dashboard's jobs page polls) says the same
    records = records_of(settings)
    records.sync(store.jobs_in_flight(), adopt=True)  # (made by the store: no row yet)
    listed = list_jobs(store, records, None, 0, 50).data
    assert [(j.id, j.progress, j.eta_seconds) for j in listed] == \
        [(job_id, detail.progress, detail.eta_seconds)]

    before = [store.frame_meta(meta, f) for f in (0, 1)]
    snap = store.snapshot(job_id)
    assert store.delete_job(job_id, statuses=("queued", "running"))
    assert not store.r.exists(store.k("job", job_id, "frame_sums"))  # (deleted with the job)
    store.restore_job(JobSnapshot.from_bytes(snap.to_bytes()))
    after = store.get_job(job_id)
    assert after.frame_sums
    for f in (0, 1):
        for name in ("err_sum", "weight_sum", "err_pixels", "look_sum", "look_sq_sum",
                     "look_pixels", "pilot_sum", "pilot_pixels"):
            assert getattr(store.frame_meta(after, f), name) == pytest.approx(
                getattr(before[f], name), rel=1e-12), (f, name)
    # A job of frames without a target keeps no frames' sums
    plain = uuid.uuid4().hex
    store.create_job(plain, "", 0, plan, b"{}", {}, time.time())
    store.put_pass(plain, 1, 0, samples(1, FIRST_LOOK).to_bytes(), ttl=60)
    assert store.merge_pass_buffer(plain, 1, 0)
    assert not store.get_job(plain).frame_sums
    assert not store.r.exists(store.k("job", plain, "frame_sums"))


def test_a_target_job_stops_its_tiles_once_the_frames_estimate_is_within_reach(store):
    """The farm's stop (services.farm.targets.adaptive_counts): once every pixel has an estimate,
    a tile takes no samples when the frame's estimated error from the job's tile summaries
    (JobMeta.expected_error) is within the rule's slack of AIM × target, though the frame's
    scale alone would still give it samples; with a target that estimate does not yet reach,
    the tile takes samples."""
    import numpy as np

    from renderer.film.adaptive import AIM, FIRST_LOOK, STOP_SLACK
    from renderer.film.buffer import SampleBuffer
    from services.farm.targets import adaptive_counts

    rng = np.random.default_rng(4)
    plan = Plan(40, 16, 4096, 16, 32)  # 3 tiles (16, 16 and 8 px wide) x passes of 32
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "", 0, plan, b"{}", {}, time.time(), target_error=0.01)
    # Before a tile's first merge: the pilot's first half, FIRST_LOOK samples every pixel of it,
    # not the pass
    pilot = adaptive_counts(store, store.get_job(job_id), 2, 0.01, 32)
    assert pilot.shape == (16, 8) and (pilot == FIRST_LOOK).all()
    assert (adaptive_counts(store, store.get_job(job_id), 2, 0.01, 3) == 3).all()
    for t in range(3):
        buf = SampleBuffer.empty(*plan.tile_rect(t))
        x = rng.exponential(1.0, size=(32,) + buf.sum.shape)
        buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), 32
        store.put_pass(job_id, t, 0, buf.to_bytes(), ttl=60)
        assert store.merge_pass_buffer(job_id, t, 0)
    meta = store.get_job(job_id)
    estimate = meta.expected_error
    assert estimate is not None
    # a target whose aim the estimate is just within the slack of: nothing to add anywhere
    reached = estimate / (AIM * (1.0 + 0.5 * STOP_SLACK))
    assert not adaptive_counts(store, meta, 0, reached, 1).any()
    # the frame's scale alone would still have given the tile samples (the same summaries but
    # an error sum far above the aim)
    assert adaptive_counts(store, dataclasses.replace(meta, err_sum=1e9), 0, reached, 1).any()
    # a target the estimate does not reach: samples
    assert adaptive_counts(store, meta, 0, estimate / (AIM * 2.0), 1).any()
    # the target the estimate is within reach of, where auto's models may add a bias of a
    # quarter of it: the samples' noise aims at the rest, which the estimate does not reach
    biased = dataclasses.replace(meta, expected_bias=0.25 * reached)
    assert adaptive_counts(store, biased, 0, reached, 1).any()
    # ... and with the target raised by the bias, the stop is where it was
    assert not adaptive_counts(store, biased, 0, 1.25 * reached, 1).any()
