"""A job whose scene asks for ``film.aovs``: ``image.exr`` of the done job is one multi-layer EXR
(the image as R, G, B, and each AOV's named channels), the same bytes before and after the job is
archived to the blob store (``services.farm.archive.frame_exr``), with the real farm."""

from __future__ import annotations

import io
import random

import numpy as np
import OpenEXR
from fastapi.testclient import TestClient

from renderer.film.aov import render_aovs
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from services.api.main import create_app
from services.farm.archive import AOV_SPP, archive_job
from services.farm.blobs import FileBlobStore
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
