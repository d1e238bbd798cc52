"""A job whose scene asks for ``film.aovs``: ``image.exr`` of the done job is one multi-layer EXR
(the image as R, G, B, and each AOV's named channels), the same bytes before and after the job is
archived to the blob store (``services.farm.archive.frame_exr``); a job with ``denoise``: the
denoised image, its noisy one as the ``noisy`` layer. With the real farm."""

from __future__ import annotations

import io
import random
import sys

import numpy as np
import OpenEXR
import pytest
from fastapi.testclient import TestClient

from renderer.film.aov import render_aovs
from renderer.film.denoise import denoise, oidn_available
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from services.api.main import create_app
from services.farm.archive import AOV_SPP, archive_job
from services.farm.blobs import FileBlobStore
from services.farm.merge import assemble
from tests.farm.conftest import records_of


def test_image_exr_of_a_job_with_aovs_has_the_layers(farm, tiny_scene, tmp_path, wait_for_job):
    settings = farm.settings.model_copy(update={"sweep_interval": 400.0, "data_dir": tmp_path})
    store = farm.store()
    scene = {**tiny_scene, "render": {**tiny_scene["render"], "seed": random.randrange(1, 2**31)},
             "film": {**tiny_scene["film"], "aovs": ["albedo", "normal", "depth", "spp"]}}
    with TestClient(create_app(settings)) as client:
        job_id = client.post("/api/jobs", json={"scene": scene, "tile_size": 16}).json()["id"]
        assert wait_for_job(client, job_id)["status"] == "done"
        before = client.get(f"/api/jobs/{job_id}/image.exr")
        assert before.status_code == 200
        mean = np.load(io.BytesIO(client.get(f"/api/jobs/{job_id}/image.npy").content))

        exr = OpenEXR.File(io.BytesIO(before.content), separate_channels=True)
        ch = {k: c.pixels for k, c in exr.channels().items()}
        assert set(ch) == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "normal.X",
                           "normal.Y", "normal.Z", "depth.Z", "spp.Y"}
        np.testing.assert_array_equal(np.stack([ch["R"], ch["G"], ch["B"]], -1), mean)
        # The traced layers are the renderer's own AOV pass of the job's scene
        want = render_aovs(compile_scene(load_scene(scene)), ["albedo", "normal", "depth"],
                           spp=AOV_SPP)
        albedo = np.stack([ch[f"albedo.{c}"] for c in "RGB"], -1).astype(np.float32)
        normal = np.stack([ch[f"normal.{c}"] for c in "XYZ"], -1).astype(np.float32)
        np.testing.assert_allclose(albedo, want["albedo"], atol=2e-3)
        np.testing.assert_allclose(normal, want["normal"], atol=2e-3)
        np.testing.assert_allclose(ch["depth.Z"], want["depth"][..., 0], rtol=1e-6)
        assert albedo.min() >= 0 and albedo.max() <= 1 and albedo.max() > 0.1
        np.testing.assert_array_equal(ch["spp.Y"], np.full((24, 32), 16.0, np.float32))

        # Archived: the blob store holds the same layered bytes
        blobs = FileBlobStore(settings.blob_path)
        assert archive_job(store, records_of(settings), blobs, job_id)
        after = client.get(f"/api/jobs/{job_id}/image.exr")
        assert after.status_code == 200 and after.content == before.content
        # and the PNG, from the image alone, still serves
        assert client.get(f"/api/jobs/{job_id}/image.png?exposure=1").status_code == 200


@pytest.mark.skipif(not oidn_available(), reason="the optional pyoidn is not installed")
def test_a_job_with_denoise_serves_the_denoised_image_and_keeps_the_noisy_layer(
        farm, tiny_scene, tmp_path, wait_for_job):
    settings = farm.settings.model_copy(update={"sweep_interval": 400.0, "data_dir": tmp_path})
    store = farm.store()
    scene = {**tiny_scene, "render": {**tiny_scene["render"], "seed": random.randrange(1, 2**31)},
             "film": {**tiny_scene["film"], "aovs": ["depth"]}}
    with TestClient(create_app(settings)) as client:
        r = client.post("/api/jobs", json={"scene": scene, "tile_size": 16, "denoise": True})
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        assert wait_for_job(client, job_id)["status"] == "done"
        noisy_mean = assemble(store, job_id)[0].mean()
        before = client.get(f"/api/jobs/{job_id}/image.exr")
        exr = OpenEXR.File(io.BytesIO(before.content), separate_channels=True)
        ch = {k: c.pixels for k, c in exr.channels().items()}
        # albedo and normal guided the denoiser but were not asked for: not layers
        assert set(ch) == {"R", "G", "B", "noisy.R", "noisy.G", "noisy.B", "depth.Z"}
        np.testing.assert_array_equal(np.stack([ch[f"noisy.{c}"] for c in "RGB"], -1),
                                      noisy_mean)
        aov = render_aovs(compile_scene(load_scene(scene)), ["albedo", "normal"], spp=AOV_SPP)
        want = denoise(noisy_mean, aov["albedo"], aov["normal"])
        beauty = np.stack([ch[c] for c in "RGB"], -1)
        assert np.all(np.isfinite(beauty))
        np.testing.assert_allclose(beauty, want, rtol=1e-3, atol=1e-4)
        assert np.abs(beauty - noisy_mean).max() > 1e-3  # it did denoise
        npy = np.load(io.BytesIO(client.get(f"/api/jobs/{job_id}/image.npy").content))
        np.testing.assert_array_equal(npy, beauty)  # every format serves the denoised image
        png = client.get(f"/api/jobs/{job_id}/image.png")

        blobs = FileBlobStore(settings.blob_path)
        assert archive_job(store, records_of(settings), blobs, job_id)
        assert client.get(f"/api/jobs/{job_id}/image.exr").content == before.content
        assert client.get(f"/api/jobs/{job_id}/image.png").content == png.content
        # the job's answer says it, from Redis and, archived, from its record
        assert r.json()["denoise"] is True
        assert client.get(f"/api/jobs/{job_id}").json()["denoise"] is True
        # ... and its listing, which reads no record's tiles' summary (migration 0007)
        page = client.get("/api/jobs", params={"limit": 500}).json()["data"]
        assert next(j for j in page if j["id"] == job_id)["denoise"] is True


def test_denoise_is_refused_naming_the_option_without_pyoidn(client, tiny_scene, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import pyoidn now raises ImportError
    r = client.post("/api/jobs", json={"scene": tiny_scene, "denoise": True})
    assert r.status_code == 422
    err = r.json()["detail"][0]
    assert err["loc"] == ["body", "denoise"] and "pyoidn" in err["msg"]


def test_denoise_must_be_a_boolean(client, tiny_scene):
    r = client.post("/api/jobs", json={"scene": tiny_scene, "denoise": "yes"})
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "denoise"]


def test_denoise_survives_a_park_snapshot():
    """A failed or cancelled job is parked as one blob and a retry restores it: the option
    goes with it (an old snapshot without it reads as False)."""
    import json

    from services.farm.planner import Plan
    from services.farm.store import JobMeta, JobSnapshot

    plan = Plan(32, 24, 16, 16, 8, 8, 1)
    for flag in (True, False):
        meta = JobMeta.new("a" * 32, "j", 0, plan, {}, 1.0, denoise=flag)
        snap = JobSnapshot(meta, b"{}", {}, {}, {}, [], [None] * plan.n_tiles)
        assert JobSnapshot.from_bytes(snap.to_bytes()).meta.denoise is flag
    line, _, rest = snap.to_bytes().partition(b"\n")
    head = json.loads(line)
    del head["meta"]["denoise"]
    old = json.dumps(head).encode() + b"\n" + rest
    assert JobSnapshot.from_bytes(old).meta.denoise is False
