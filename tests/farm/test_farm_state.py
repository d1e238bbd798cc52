"""Farm state that lasts (issue #20): job records in SQL, finished jobs' images in the blob store,
Redis left with what is in flight; retention; the database or Redis going away.

Against a real Redis and the configured database: SQLite in the test's data folder, or the
PostgreSQL of ``DATABASE_URL`` (a schema per test: tests/conftest.py ``farm_state``).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
import os
import socket
import socketserver
import threading
import time
import uuid

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import inspect

from renderer.render import render
from services.api.main import create_app
from services.farm.archive import Archive
from services.farm.blobs import FileBlobStore
from services.farm.planner import Plan
from services.farm.records import Records
from services.farm.settings import Settings
from services.farm.store import JobMeta, JobStore
from services.launcher import EmbeddedRedis, start_worker, terminate
from tests.conftest import drop_farm_state, farm_state
from tests.farm.conftest import (
    WORKER_START_TIMEOUT,
    archived,
    assert_archived_whole,
    job_keys,
    records_of,
)


def _meta(created_at: float, status: str = "done", name: str = "") -> JobMeta:
    finished = created_at + 1 if status in ("done", "failed", "cancelled") else None
    return JobMeta(uuid.uuid4().hex, name, status, 0, Plan(32, 24, 16, 16, 8), 0, 0, 0, 0,
                   created_at, created_at, finished, None, {})


def _image(client, job_id, fmt="npy"):
    r = client.get(f"/api/jobs/{job_id}/image.{fmt}")
    assert r.status_code == 200, r.text
    return np.load(io.BytesIO(r.content)) if fmt == "npy" else r.content


# --- 1. job records in SQL -----------------------------------------------------------------------


def test_migration_at_start_up_is_idempotent(settings):
    """The schema is upgraded when the API starts, and starting again (or migrating again by
    hand) changes nothing and keeps the rows."""
    with TestClient(create_app(settings)) as c:
        assert c.get("/readyz").json() == {"status": "ok"}
    records = records_of(settings)
    assert records.revision() == "0002"
    records.create(_meta(time.time()))
    records.migrate()
    with TestClient(create_app(settings)) as c:
        assert c.get("/api/jobs").json()["count"] == 1
    assert records.revision() == "0002"
    indexes = {i["name"] for i in inspect(records.engine).get_indexes("jobs")}
    assert {"jobs_created_at", "jobs_status_created_at", "jobs_finished_at"} <= indexes


def test_the_counts_migration_counts_the_jobs_already_there(tmp_path):
    """A database at the first migration, with jobs in it, upgraded: the counts by status
    (kept by triggers from then on) start from the jobs it has."""
    records = Records(f"sqlite:///{tmp_path}/old.db")
    records.migrate("0001")
    t0 = time.time()
    for status in ("done", "done", "failed", "running"):
        records.create(_meta(t0, status))
    records.migrate()
    assert records.revision() == "0002"
    assert records.count_by_status() == {"queued": 0, "running": 1, "done": 2, "failed": 1,
                                         "cancelled": 0}
    first = records.page("done")[0][0].meta
    records.sync([dataclasses.replace(first, status="failed")])
    records.delete(records.page("running")[0][0].meta.id)
    assert records.count_by_status() == {"queued": 0, "running": 0, "done": 1, "failed": 2,
                                         "cancelled": 0}
    assert records.page()[1] == 3 and records.page("failed")[1] == 2


def test_listing_pages_and_filters_in_the_database(client, settings):
    """Jobs Redis does not hold (archived ones) are listed from their records: newest first,
    paged by offset and limit, filtered by status, with the total that matches."""
    records = records_of(settings)
    t0 = time.time() - 1000
    metas = [_meta(t0 + i, "done" if i % 3 else "failed", f"job {i}") for i in range(25)]
    for m in metas:
        records.create(m)
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


def test_a_named_token_is_recorded_as_the_submitter(redis_base_url, tmp_path, tiny_scene):
    prefix = f"lucent-test-{uuid.uuid4().hex[:10]}"
    settings = Settings(redis_url=redis_base_url, key_prefix=prefix,
                        api_tokens="alice:a-s3cret,bob:b-s3cret", **farm_state(prefix, tmp_path))
    try:
        with TestClient(create_app(settings)) as c:
            assert c.get("/api/jobs").status_code == 401
            r = c.post("/api/jobs", json={"scene": tiny_scene},
                       headers={"Authorization": "Bearer b-s3cret"})
            assert r.status_code == 201, r.text
            assert r.json()["submitter"] == "bob"
            listed = c.get("/api/jobs", headers={"Authorization": "Bearer a-s3cret"}).json()
            assert [j["submitter"] for j in listed["data"]] == ["bob"]
        assert records_of(settings).get(r.json()["id"]).meta.submitter == "bob"
    finally:
        drop_farm_state(settings)


# --- 2. finished jobs leave Redis ----------------------------------------------------------------


def test_finished_jobs_leave_nothing_in_redis(farm, farm_client, wait_for_job, wait_until,
                                              tiny_scene):
    """Done, failed and cancelled jobs are archived: record final, image in the blob store,
    and no key, list entry or pending pass of theirs left in Redis; their images and details
    are served from the archive."""
    store, records = farm.store(), farm.records()
    done = farm_client.post("/api/jobs", json={"scene": tiny_scene}).json()["id"]
    long = copy.deepcopy(tiny_scene)
    long["render"]["spp"] = 1024
    cancelled = farm_client.post("/api/jobs", json={"scene": long, "spp_per_pass": 2,
                                                    "max_spp_per_pass": 2}).json()["id"]
    wait_until(lambda: farm_client.get(f"/api/jobs/{cancelled}").json()["tasks_merged"] > 0,
               120, "a merged pass")
    assert farm_client.delete(f"/api/jobs/{cancelled}").json()["status"] == "cancelled"
    bad = copy.deepcopy(tiny_scene)
    bad["background"] = [1e308, 1e308, 1e308]
    bad["objects"] = [{"type": "sphere", "center": [0, 0, 0], "radius": 0.5,
                       "material": "white"}]
    failed = farm_client.post("/api/jobs", json={"scene": bad}).json()["id"]
    assert_archived_whole(records, store, done, 16)
    for job_id, status in [(cancelled, "cancelled"), (failed, "failed")]:
        record = archived(records, job_id)
        assert record.meta.status == status
        wait_until(lambda j=job_id: not job_keys(store, j), 30, f"{job_id}'s keys gone")
    assert not [k for k in store.r.scan_iter(match=f"{store.k('job')}:*")
                if any(j in k.decode() for j in (done, cancelled, failed))]
    np.testing.assert_allclose(_image(farm_client, done), render(tiny_scene), rtol=1e-5,
                               atol=1e-7)
    png = farm_client.get(f"/api/jobs/{done}/image.png")
    assert png.content[:4] == b"\x89PNG"
    assert farm_client.get(f"/api/jobs/{done}/image.png",
                           headers={"If-None-Match": png.headers["etag"]}).status_code == 304
    brighter = farm_client.get(f"/api/jobs/{done}/image.png", params={"exposure": 1})
    assert brighter.status_code == 200 and brighter.content != png.content
    assert _image(farm_client, cancelled).any()  # the partial image stays available
    detail = farm_client.get(f"/api/jobs/{done}").json()
    assert {t["samples"] for t in detail["tile_states"]} == {16}


def test_a_retried_archived_job_carries_on_where_it_stopped(farm, farm_client, wait_for_job,
                                                            wait_until, tiny_scene):
    """A cancelled job, archived with its merged samples, is put back in Redis by retry and
    renders only what it had left: the image is the local render's, every pixel at spp."""
    records = farm.records()
    scene = copy.deepcopy(tiny_scene)
    scene["render"]["spp"] = 64
    job_id = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 16,
                                                 "spp_per_pass": 2, "max_spp_per_pass": 2}
                              ).json()["id"]
    wait_until(lambda: farm_client.get(f"/api/jobs/{job_id}").json()["tasks_merged"] >= 8, 120,
               "passes merged")
    farm_client.delete(f"/api/jobs/{job_id}")
    before = archived(records, job_id).meta.tasks_merged
    assert 8 <= before < 128
    again = farm_client.post(f"/api/jobs/{job_id}/retry").json()
    assert again["status"] == "running" and again["tasks_merged"] >= before
    assert wait_for_job(farm_client, job_id)["status"] == "done"
    assert_archived_whole(records, farm.store(), job_id, 64)
    np.testing.assert_allclose(_image(farm_client, job_id), render(scene), rtol=1e-5, atol=1e-7)


def test_history_survives_a_redis_restart(tmp_path, tiny_scene):
    """Redis restarted empty (no persistence) once every job finished: nothing of the history
    is lost, as none of it was in Redis any more."""
    server = EmbeddedRedis().start()
    prefix = f"lucent-test-{uuid.uuid4().hex[:10]}"
    settings = Settings(redis_url=server.url, key_prefix=prefix, sweep_interval=0.2,
                        **farm_state(prefix, tmp_path))
    worker = start_worker(server.url, concurrency=1, name=f"{prefix}@%h",
                          extra_env={"LUCENT_KEY_PREFIX": prefix, "LUCENT_API_TOKEN": ""},
                          log=open(tmp_path / "worker.log", "w"))
    try:
        records = records_of(settings)
        with TestClient(create_app(settings)) as api:
            ids = [api.post("/api/jobs", json={"scene": tiny_scene, "name": f"n{i}"}).json()["id"]
                   for i in range(3)]
            for job_id in ids:
                archived(records, job_id, WORKER_START_TIMEOUT)
            pngs = {j: _image(api, j, "png") for j in ids}
        terminate(worker, 30.0)
        port = server.port
        server.stop()
        server = EmbeddedRedis(port=port).start()  # empty
        with TestClient(create_app(settings)) as api:
            listed = api.get("/api/jobs").json()
            assert listed["count"] == 3
            assert {(j["id"], j["status"]) for j in listed["data"]} == {(j, "done") for j in ids}
            assert {j: _image(api, j, "png") for j in ids} == pngs
    finally:
        terminate(worker, 30.0)
        server.stop()
        drop_farm_state(settings)


# --- 3. retention ---------------------------------------------------------------------------------


def _archived_job(archive: Archive, store: JobStore, created_at: float, status: str) -> str:
    """A job that finished without rendering (cancelled or failed at once), then archived."""
    job_id = uuid.uuid4().hex
    meta = store.create_job(job_id, "", 0, Plan(32, 24, 16, 16, 8), b'{"scene": 1}',
                            created_at=created_at)
    archive.records.create(meta)
    store.transition(job_id, status, ("queued",), "finished_at")
    store.r.hset(store.job_key(job_id), "finished_at", created_at + 1)  # finished long ago
    assert archive.archive(job_id)
    return job_id


def test_delete_removes_a_finished_job_everywhere(client, settings, store):
    archive: Archive = client.app.state.archive
    job_id = _archived_job(archive, store, time.time(), "cancelled")
    folder = settings.blob_root / "jobs" / job_id
    assert (folder / "image.exr").exists() and (folder / "scene.json").exists()
    r = client.delete(f"/api/jobs/{job_id}")
    assert r.status_code == 204
    assert client.get(f"/api/jobs/{job_id}").status_code == 404
    assert client.get(f"/api/jobs/{job_id}/image.png").status_code == 404
    assert client.delete(f"/api/jobs/{job_id}").status_code == 404
    assert archive.records.get(job_id) is None and not folder.exists()
    assert not job_keys(store, job_id)


def test_retention_deletes_old_jobs_and_caps_images(client, settings, store):
    """LUCENT_KEEP_DAYS deletes jobs that finished longer ago; LUCENT_MAX_IMAGE_BYTES removes
    the oldest images first and keeps their records (their image routes answer 410)."""
    archive: Archive = client.app.state.archive
    now = time.time()
    old, middle, new = (_archived_job(archive, store, now - age, "failed")
                        for age in (10 * 86400, 3 * 86400, 60))
    size = archive.records.get(new).image_bytes
    assert size > 0
    capped = Archive(store, archive.records, archive.blobs,
                     settings.model_copy(update={"keep_days": 7.0, "max_image_bytes": size}))
    with pytest.raises(ValueError):
        Settings(keep_days=0)
    # The sweep claims the round first, as the sweeper's thread does every retention_interval
    capped.sweep(now + 5)
    assert archive.records.get(old) is None
    assert not (settings.blob_root / "jobs" / old).exists()
    kept = archive.records.get(middle)
    assert kept is not None and kept.image_removed_at is not None and kept.image_bytes == 0
    r = client.get(f"/api/jobs/{middle}/image.exr")
    assert r.status_code == 410 and "LUCENT_MAX_IMAGE_BYTES" in r.json()["detail"]
    assert client.get(f"/api/jobs/{new}/image.exr").status_code == 200
    assert client.get("/api/jobs").json()["count"] == 2


# --- 4. the database going away mid-job ----------------------------------------------------------


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
    SQLite: its folder gone): the routes that need it answer 503 naming it, the job goes on in
    Redis (its status is still served), and once the database is back it is archived whole."""
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
    scene["render"]["spp"] = 128
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
                assert r.json()["detail"].startswith("the job database"), r.text
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
            assert_archived_whole(records, store, job_id, 128)
            np.testing.assert_allclose(_image(api, job_id), render(scene), rtol=1e-5, atol=1e-7)
            assert api.get("/readyz").status_code == 200
    finally:
        if proxy is not None:
            proxy.shutdown()
            proxy.server_close()
        drop_farm_state(settings.model_copy(update={"database_url": url}) if url else settings)


def test_blob_keys_cannot_leave_the_store(tmp_path):
    blobs = FileBlobStore(tmp_path / "blobs")
    for key in ("../x", "jobs/../../x", "/etc/passwd", "Jobs/A", "jobs//x", ""):
        with pytest.raises(ValueError):
            blobs.put(key, b"x")
    assert blobs.put("jobs/ab/image.png", b"png") == 3
    assert blobs.get("jobs/ab/image.png") == b"png"
    blobs.delete("jobs/ab")
    assert blobs.get("jobs/ab/image.png") is None
