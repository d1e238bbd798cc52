"""The blob store in an S3-compatible bucket (``LUCENT_BLOB_URL=s3://bucket/prefix``).

The server is moto's S3 server (``moto.server.ThreadedMotoServer``: the S3 REST API over HTTP on
a local port, an emulator, not AWS or MinIO), reached by boto3 as any S3-compatible endpoint is
(``AWS_ENDPOINT_URL_S3``). The same contract is checked on the folder store, and a farm (the API
and a worker process) runs a job whose mesh and image live in the bucket.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.blobs import (
    FileBlobStore,
    S3BlobStore,
    asset_reader,
    content_key,
    open_blob_store,
    put_content,
)
from services.farm.settings import Settings
from services.launcher import free_port, start_worker, terminate
from tests.conftest import wait_until
from tests.farm.conftest import WORKER_START_TIMEOUT, drop_farm_state, farm_state, wait_for_job

boto3 = pytest.importorskip("boto3")
moto_server = pytest.importorskip("moto.server")

QUAD_OBJ = b"v -1 -1 -3\nv 1 -1 -3\nv 1 1 -3\nv -1 1 -3\nf 1 2 3\nf 1 3 4\n"


@pytest.fixture(scope="module")
def s3_endpoint() -> Iterator[str]:
    port = free_port()
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port)
    server.start()
    env = {"AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{port}", "AWS_ACCESS_KEY_ID": "lucent",
           "AWS_SECRET_ACCESS_KEY": "lucent-test", "AWS_DEFAULT_REGION": "us-east-1"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield env["AWS_ENDPOINT_URL_S3"]
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        server.stop()


@pytest.fixture
def bucket(s3_endpoint: str) -> str:
    name = f"lucent-{uuid.uuid4().hex[:12]}"
    boto3.client("s3").create_bucket(Bucket=name)
    return name


def objects(bucket: str) -> list[str]:
    reply = boto3.client("s3").list_objects_v2(Bucket=bucket)
    return sorted(o["Key"] for o in reply.get("Contents", []))


@pytest.fixture(params=["folder", "s3"])
def blobs(request, tmp_path: Path):
    if request.param == "folder":
        return FileBlobStore(tmp_path / "blobs")
    return S3BlobStore(request.getfixturevalue("bucket"), "farm-a/")


def test_the_blob_store_contract(blobs):
    """Both stores: put, get, exists, delete by content address; a missing key is None / False
    and deleting it does nothing; a key that is not a content address is refused before any
    request (never a path or an object name from outside)."""
    data = os.urandom(3000)
    key = put_content(blobs, data)
    assert key == content_key(data)
    assert blobs.exists(key) and blobs.get(key) == data
    assert put_content(blobs, data) == key  # stored once
    assert asset_reader(blobs)(key) == data
    other = content_key(b"not stored")
    assert not blobs.exists(other) and blobs.get(other) is None
    blobs.delete(other)
    blobs.delete(key)
    assert not blobs.exists(key) and blobs.get(key) is None
    with pytest.raises(KeyError):
        asset_reader(blobs)(key)
    for bad in ["../etc/passwd", "sha256:" + "0" * 63, "sha256:" + "A" * 64, "farm-a/x"]:
        with pytest.raises(ValueError, match="not a blob key"):
            blobs.put(bad, b"x")
        with pytest.raises(KeyError):
            asset_reader(blobs)(bad)


def test_s3_objects_are_named_under_the_prefix(bucket):
    store = S3BlobStore(bucket, "/studio/farm/")
    key = put_content(store, b"an image")
    digest = key.removeprefix("sha256:")
    assert objects(bucket) == [f"studio/farm/sha256/{digest[:2]}/{digest}"]
    assert S3BlobStore(bucket).get(key) is None  # another prefix, another store


def test_open_blob_store_reads_the_location(tmp_path, bucket):
    assert isinstance(open_blob_store(tmp_path), FileBlobStore)
    store = open_blob_store(f"s3://{bucket}/p")
    assert isinstance(store, S3BlobStore) and (store.bucket, store.prefix) == (bucket, "p/")
    assert open_blob_store(f"s3://{bucket}/p") is store  # one client per process and location
    with pytest.raises(ValueError, match="not an S3 location"):
        open_blob_store("s3://A_bucket!")
    with pytest.raises(ValueError, match="blob_url"):
        Settings(blob_url="https://example.com/bucket")
    assert Settings(blob_url=f"s3://{bucket}").blob_location == f"s3://{bucket}"


def test_a_farm_on_s3_keeps_assets_and_images_in_the_bucket(redis_base_url, bucket, tmp_path,
                                                            tiny_scene):
    """The API and a worker process with ``LUCENT_BLOB_URL``: a mesh uploaded as an asset goes
    to the bucket, the worker reads it from there and renders it, the done job's EXR and PNG are
    written there and served from there, and deleting the job deletes them; nothing of it is in
    a data folder."""
    prefix = f"lucent-test-{uuid.uuid4().hex[:10]}"
    location = f"s3://{bucket}/farm"
    settings = Settings(redis_url=redis_base_url, key_prefix=prefix, heartbeat_interval=0.5,
                        blob_url=location, **farm_state(prefix, tmp_path / "data"))
    log_path = tmp_path / "worker.log"
    with open(log_path, "w") as log:
        proc = start_worker(redis_base_url, concurrency=1, threads=1, name=f"{prefix}@%h",
                            log=log, extra_env={
                                "LUCENT_KEY_PREFIX": prefix, "LUCENT_HEARTBEAT_INTERVAL": "0.5",
                                "LUCENT_API_TOKEN": "", "LUCENT_BLOB_URL": location,
                                "LUCENT_CACHE_DIR": os.environ.get("LUCENT_CACHE_DIR", ""),
                                "XDG_CACHE_HOME": str(tmp_path / "cache")})
        try:
            with TestClient(create_app(settings)) as client:
                wait_until(lambda: any(w.get("state") == "idle" for w in
                                       client.get("/api/workers").json()["data"])
                           or proc.poll() is not None,
                           WORKER_START_TIMEOUT, "a warm worker process", interval=0.2)
                assert proc.poll() is None, log_path.read_text()[-3000:]
                r = client.post("/api/assets", content=QUAD_OBJ)
                assert r.status_code == 201, r.text
                mesh = r.json()["asset"]
                assert mesh == content_key(QUAD_OBJ)
                digest = mesh.removeprefix("sha256:")
                assert objects(bucket) == [f"farm/sha256/{digest[:2]}/{digest}"]
                material = next(iter(tiny_scene["materials"]))
                scene = {**tiny_scene, "objects": [*tiny_scene["objects"], {
                    "type": "mesh", "asset": mesh, "material": material}]}
                r = client.post("/api/jobs", json={"scene": scene, "tile_size": 16})
                assert r.status_code == 201, r.text
                job = wait_for_job(client, r.json()["id"])
                assert job["status"] == "done", (job, log_path.read_text()[-3000:])
                # the sweeper archives the done job: its EXR and PNG join the asset
                wait_until(lambda: len(objects(bucket)) == 3, 60, "the images in the bucket")
                png = client.get(f"/api/jobs/{job['id']}/image.png").content
                exr = client.get(f"/api/jobs/{job['id']}/image.exr").content
                stored = set(objects(bucket))
                for data in (png, exr):
                    d = content_key(data).removeprefix("sha256:")
                    assert f"farm/sha256/{d[:2]}/{d}" in stored
                assert not (tmp_path / "data" / "blobs").exists()
                assert client.delete(f"/api/jobs/{job['id']}").status_code == 204
                assert objects(bucket) == [f"farm/sha256/{digest[:2]}/{digest}"]  # the asset
        finally:
            terminate(proc, 30.0)
            drop_farm_state(settings)
