"""What the dashboard adds to the service, without a browser: the pages at ``/``, the example and
figure allow-lists (nothing outside them can be read), the preview's exposure and ETag, the
workers' clock."""

from __future__ import annotations

import io
import json
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import redis
from fastapi.testclient import TestClient
from PIL import Image

from renderer.film.buffer import SampleBuffer
from services.api.main import create_app
from services.api.routes.dashboard import find_examples
from services.farm.merge import merge_pass
from services.farm.planner import Plan
from services.farm.settings import Settings
from services.farm.store import JobStore

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def settings(redis_base_url: str) -> Settings:
    return Settings(redis_url=redis_base_url, key_prefix=f"lucent-dapi-{uuid.uuid4().hex[:10]}")


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def test_the_pages_are_served_at_the_root(client):
    r = client.get("/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert '<script type="module" src="/dashboard/app.js">' in r.text
    for name in ("app.js", "api.js", "jobs.js", "job.js", "workers.js", "submit.js",
                 "methods.js", "app.css"):
        assert client.get(f"/dashboard/{name}").status_code == 200, name
    assert client.get("/dashboard/nope.js").status_code == 404


def test_examples_are_listed_without_those_that_reference_mesh_files(client):
    names = [e["name"] for e in client.get("/api/examples").json()["data"]]
    assert "cornell_box" in names
    assert "mesh_torus" not in names  # objects[].path = meshes/torus.ply
    for name in names:
        scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        assert all("path" not in o for o in scene["objects"])
    cornell = client.get("/api/examples/cornell_box").json()
    assert cornell == json.loads((ROOT / "examples" / "cornell_box.json").read_text())


@pytest.mark.parametrize("name", [
    "mesh_torus", "../pyproject", "..%2Fpyproject", "%2Fetc%2Fpasswd", "cornell_box.json",
    "meshes", "make_examples",
])
def test_only_listed_examples_can_be_read(client, name):
    assert client.get(f"/api/examples/{name}").status_code in (404, 405), name


def test_the_allow_list_reads_only_json_files_in_its_folder(tmp_path):
    (tmp_path / "ok.json").write_text('{"film": {"width": 8, "height": 4}, "objects": []}')
    (tmp_path / "mesh.json").write_text('{"objects": [{"type": "mesh", "path": "x.ply"}]}')
    (tmp_path / "broken.json").write_text("{")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "deep.json").write_text("{}")
    (tmp_path / "notes.txt").write_text("{}")
    found = find_examples(tmp_path)
    assert list(found) == ["ok"] and (found["ok"].width, found["ok"].height) == (8, 4)
    assert find_examples(tmp_path / "missing") == {}


def test_figures_are_listed_and_served_by_name_only(client):
    figures = client.get("/api/figures").json()["data"]
    on_disk = sorted(p.name for p in (ROOT / "docs" / "images" / "methods").glob("*.png"))
    on_disk += sorted("accuracy-" + p.name
                      for p in (ROOT / "docs" / "images" / "accuracy").glob("*.png"))
    assert [f["name"] for f in figures] == on_disk
    for f in figures:
        r = client.get(f["url"])
        assert r.status_code == 200 and r.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert client.get("/dashboard/figures/..%2F..%2Fcornell_box.png").status_code == 404
    assert client.get("/dashboard/figures/nope.png").status_code == 404


def test_examples_and_figures_need_the_token_when_one_is_set(redis_base_url):
    settings = Settings(redis_url=redis_base_url, key_prefix="lucent-dapi-token",
                        api_token="s3cret")
    with TestClient(create_app(settings)) as c:
        assert c.get("/api/examples").status_code == 401
        assert c.get("/api/figures").status_code == 401
        assert c.get("/").status_code == 200  # the page itself holds no farm data


J1 = uuid.uuid4().hex  # the API answers 404 to an id of another form


def _job_with_one_merged_pass(settings: Settings, value: float) -> str:
    store = JobStore(redis.Redis.from_url(settings.redis_url), settings.key_prefix)
    plan = Plan(width=16, height=8, spp=16, tile_size=8, spp_per_pass=8)
    store.create_job(J1, "", 0, plan, "{}")
    for tile, x0 in ((0, 0), (1, 8)):
        buf = SampleBuffer.empty(x0, 0, 8, 8)
        buf.sum[:] = value * 8
        buf.sum_sq[:] = value * value * 8
        buf.count[:] = 8
        store.put_pass(J1, tile, 0, buf.to_bytes(), ttl=60)
        merge_pass(store, J1, tile, 0)
    store.r.close()
    return J1


def _mean(png: bytes) -> float:
    return float(np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).mean())


def test_exposure_brightens_the_preview_and_changes_its_etag(client, settings):
    job = _job_with_one_merged_pass(settings, 0.05)
    base = client.get(f"/api/jobs/{job}/image.png")
    bright = client.get(f"/api/jobs/{job}/image.png", params={"exposure": 2})
    dark = client.get(f"/api/jobs/{job}/image.png", params={"exposure": -2})
    assert _mean(dark.content) < _mean(base.content) < _mean(bright.content)
    assert len({base.headers["etag"], bright.headers["etag"], dark.headers["etag"]}) == 3
    # The dashboard sends the ETag back: an unchanged image is a 304 with no body.
    again = client.get(f"/api/jobs/{job}/image.png", params={"exposure": 2},
                       headers={"If-None-Match": bright.headers["etag"]})
    assert again.status_code == 304 and again.content == b""
    # The job's status says the same version without touching the image.
    assert client.get(f"/api/jobs/{job}").json()["image_version"] == 2


def test_workers_carry_the_service_clock(client):
    body = client.get("/api/workers").json()
    assert body["server_time"] > 1.7e9 and body["heartbeat_interval"] > 0
