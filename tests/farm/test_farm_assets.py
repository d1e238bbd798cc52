"""Assets (``/api/assets``, issue #20): files uploaded once, content addressed, checked when a
job names them, read by the workers through the blob store and their on-disk cache."""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path

from fastapi.testclient import TestClient
from PIL import Image

from services.api.main import create_app
from services.client import Client, scene_for_upload
from services.farm.blobs import AssetCache, FileBlobStore

# A square of two triangles in front of the camera, 0.5 units wide.
QUAD_OBJ = b"""# a quad
v -0.25 -0.25 0
v 0.25 -0.25 0
v 0.25 0.25 0
v -0.25 0.25 0
f 1 2 3
f 1 3 4
"""


def test_upload_head_get_and_bad_uploads(settings):
    settings = settings.model_copy(update={"max_asset_bytes": 4096})
    with TestClient(create_app(settings)) as client:
        name = "sha256:" + hashlib.sha256(QUAD_OBJ).hexdigest()
        assert client.head(f"/api/assets/{name}").status_code == 404
        r = client.post("/api/assets", content=QUAD_OBJ,
                        params={"sha256": name.removeprefix("sha256:")})
        assert r.status_code == 201, r.text
        assert r.json() == {"asset": name, "bytes": len(QUAD_OBJ), "kind": "obj"}
        assert client.post("/api/assets", content=QUAD_OBJ).json()["asset"] == name  # once
        assert client.head(f"/api/assets/{name}").status_code == 200
        assert client.get(f"/api/assets/{name}").content == QUAD_OBJ
        # truncated on the way: the hash the client sent does not match the bytes
        r = client.post("/api/assets", content=QUAD_OBJ[:-10],
                        params={"sha256": name.removeprefix("sha256:")})
        assert r.status_code == 422 and "sha256" in r.text and "truncated" in r.text
        # not a kind of file a scene reads
        r = client.post("/api/assets", content=b"\x00\x01binary junk")
        assert r.status_code == 422 and "not a kind of file" in r.text
        # over the limit
        r = client.post("/api/assets", content=QUAD_OBJ * 100)
        assert r.status_code == 413


def test_a_scene_naming_an_asset_of_the_wrong_kind_is_422(client, tiny_scene):
    """An image uploaded, then named as a mesh: refused at submission, naming the field."""
    png = io.BytesIO()
    Image.new("RGB", (2, 2)).save(png, format="PNG")
    name = client.post("/api/assets", content=png.getvalue()).json()["asset"]
    material = next(iter(tiny_scene["materials"]))
    scene = {**tiny_scene, "objects": [*tiny_scene["objects"], {
        "type": "mesh", "asset": name, "material": material}]}
    r = client.post("/api/jobs", json={"scene": scene})
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["loc"] == ["body", "scene", "objects", len(scene["objects"]) - 1, "asset"]
    assert "PNG" in error["msg"] and "OBJ" in error["msg"]


def test_the_worker_cache_is_bounded(tmp_path):
    blobs = FileBlobStore(tmp_path / "blobs")
    names = []
    for i in range(3):
        data = QUAD_OBJ + b"# " + bytes([65 + i]) * 1000 + b"\n"
        name = "sha256:" + hashlib.sha256(data).hexdigest()
        blobs.put(name, data)
        names.append((name, data))
    cache = AssetCache(blobs, tmp_path / "cache", max_bytes=2500)
    for name, data in names:
        assert cache.read(name) == data
    assert cache.fetched == 3
    held = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert sum((tmp_path / "cache" / p).stat().st_size for p in held) <= 2500
    assert names[-1][0].removeprefix("sha256:") in held  # the newest kept
    assert cache.read(names[-1][0]) == names[-1][1] and cache.fetched == 3  # from the cache


def test_a_mesh_asset_renders_on_the_farm(farm, tiny_scene, tmp_path, wait_for_job):
    """A scene file naming a mesh by path, as ``lucent submit`` sends it: the mesh uploaded as
    an asset (once: a second submission only asks whether the farm has it), the reference
    rewritten; the job is accepted and the workers (reading the blob store the API wrote) render
    it; the quad shows in the image."""
    # the session's workers read LUCENT_DATA_DIR's blob store: the API writes there too
    blob_dir = Path(os.environ["LUCENT_DATA_DIR"]) / "blobs"
    settings = farm.settings.model_copy(update={"data_dir": tmp_path, "blob_dir": blob_dir})
    (tmp_path / "quad.obj").write_bytes(QUAD_OBJ + os.urandom(8).hex().encode() + b"\n")
    material = next(iter(tiny_scene["materials"]))
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps({**tiny_scene, "objects": [*tiny_scene["objects"], {
        "type": "mesh", "path": "quad.obj", "material": material}]}))
    with TestClient(create_app(settings)) as client:
        cli = Client("http://testserver")
        cli.http = client  # the client's requests, to this app
        sent: list[str] = []
        client.event_hooks["request"].append(lambda req: sent.append(req.method))
        scene = scene_for_upload(scene_file, cli)
        assert sent == ["HEAD", "POST"]
        assert scene_for_upload(scene_file, cli) == scene and sent == ["HEAD", "POST", "HEAD"]
        name = scene["objects"][-1]["asset"]
        assert "path" not in scene["objects"][-1]
        assert client.get(f"/api/assets/{name}").content == (tmp_path / "quad.obj").read_bytes()
        r = client.post("/api/jobs", json={"scene": scene, "tile_size": 16})
        assert r.status_code == 201, r.text
        job = wait_for_job(client, r.json()["id"])
        assert job["status"] == "done", job
        r = client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": 16})
        assert wait_for_job(client, r.json()["id"])["status"] == "done"
        with_quad = client.get(f"/api/jobs/{job['id']}/image.png").content
        without = client.get(f"/api/jobs/{r.json()['id']}/image.png").content
        assert with_quad != without


def test_submit_uploads_the_environment_image(tmp_path):
    """``lucent submit`` sends the environment image as an asset too, and rewrites its
    reference; an asset reference is left alone."""
    from renderer.scene.files import digest

    class Uploads:
        def __init__(self):
            self.sent: list[bytes] = []

        def upload_asset(self, data: bytes) -> str:
            self.sent.append(data)
            return digest(data)

    (tmp_path / "sky.exr").write_bytes(b"v/1\x01 a sky")
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps({"environment": {"image": "sky.exr", "scale": 2}}))
    uploads = Uploads()
    scene = scene_for_upload(scene_file, uploads)  # type: ignore[arg-type]
    assert scene["environment"] == {"image": {"asset": digest(b"v/1\x01 a sky")}, "scale": 2}
    scene_file.write_text(json.dumps(scene))
    assert scene_for_upload(scene_file, uploads) == scene  # type: ignore[arg-type]
    assert uploads.sent == [b"v/1\x01 a sky"]


def test_submit_uploads_texture_images(tmp_path):
    """``lucent submit`` sends each bitmap texture's image as an asset (on any colour parameter)
    and rewrites its reference; colours and checkerboards stay as they are."""
    from renderer.scene.files import digest

    sent: list[bytes] = []

    class Uploads:
        def upload_asset(self, data: bytes) -> str:
            sent.append(data)
            return digest(data)

    (tmp_path / "wood.png").write_bytes(b"\x89PNG wood")
    (tmp_path / "rust.png").write_bytes(b"\x89PNG rust")
    checker = {"type": "checkerboard", "scale": [4, 4]}
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps({"materials": {
        "floor": {"type": "diffuse", "albedo": {"type": "bitmap", "image": "wood.png"}},
        "metal": {"type": "phong", "diffuse": checker,
                  "specular": {"type": "bitmap", "image": "rust.png", "scale": [2, 2]}},
        "plain": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}}))
    scene = scene_for_upload(scene_file, Uploads())  # type: ignore[arg-type]
    materials = scene["materials"]
    assert materials["floor"]["albedo"]["image"] == {"asset": digest(b"\x89PNG wood")}
    assert materials["metal"]["specular"] == {"type": "bitmap", "scale": [2, 2],
                                              "image": {"asset": digest(b"\x89PNG rust")}}
    assert materials["metal"]["diffuse"] == checker and sent == [b"\x89PNG wood", b"\x89PNG rust"]
