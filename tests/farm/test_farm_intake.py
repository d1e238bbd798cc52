"""Reading submissions off the event loop (``services/api/intake.py``): a large body is parsed and
checked in a process of its own, with the same answers as a small one, while ``/healthz`` keeps
answering. Timing is asserted loosely (a share of the submission's own time); the figures are
``python -m bench.submit_latency``'s."""

from __future__ import annotations

import gc
import json
import threading
import time
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from renderer.geometry.meshgen import sheet
from services.api.main import create_app
from services.farm.settings import Settings


def grid_mesh(n: int) -> dict:
    """An n x n grid of quads (2 n² triangles): about 110 n² bytes of JSON."""
    vertices, triangles = sheet(n, z=0.123456789)
    return {"type": "mesh", "vertices": vertices.tolist(), "triangles": triangles.tolist(),
            "material": "white"}


@pytest.fixture
def process_client(settings: Settings) -> Iterator[TestClient]:
    """The API reading every non-empty body in its intake process."""
    with TestClient(create_app(settings.model_copy(update={"intake_inline_bytes": 0}))) as c:
        yield c


def post_raw(client: TestClient, body: bytes | str, content_type: str = "application/json"):
    return client.post("/api/jobs", content=body, headers={"content-type": content_type})


def test_a_body_read_in_the_intake_process_gets_the_same_answers(process_client, client,
                                                                 tiny_scene):
    """Each answer as the thread pool gives it (``client``: bodies up to 1 MiB are read there)."""
    scene = json.dumps({"scene": tiny_scene})
    cases = [
        scene,
        json.dumps({"scene": {**tiny_scene, "film": {"width": 0, "height": 8}}}),
        scene[:-1] + ', "name": ' + "[" * 500 + "1" + "]" * 500 + "}",
        scene[:-1] + ', "tilesize": 16}',
        scene[:-1] + ', "tile_size": "16"}',
        '{"scene": {}',
        "[" * 10_000 + "]" * 10_000,
        "null",
        b'{"scene": "\xff"}',
    ]
    for body in cases:
        here, there = post_raw(client, body), post_raw(process_client, body)
        assert there.status_code == here.status_code, (body[:80], there.text[:300])
        if here.status_code == 201:
            assert there.json()["tasks_total"] == here.json()["tasks_total"]
        else:
            assert there.json() == here.json(), body[:80]
    # A body that says it is not JSON is refused as FastAPI refused it
    for c in (client, process_client):
        r = post_raw(c, scene, "text/plain")
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body"]
    assert process_client.get("/api/jobs").json()["count"] == 2  # one each, same prefix


def test_healthz_answers_while_a_large_scene_is_read(client, tiny_scene):
    """A 6 MB scene (bodies over 1 MiB are read in the intake process): /healthz keeps
    answering. Before, the body's json.loads ran on the event loop, holding it (and the GIL) for a
    quarter of the submission's time; the bound is a tenth of it, loose against the few
    milliseconds /healthz takes (bench/submit_latency.py measures it)."""
    # 105 800 triangles, as JSON text: the test keeps no million Python objects alive, whose
    # garbage collection would stall this process's event loop (it is the test's, not the API's)
    tiny_scene["objects"].append("MESH")
    body = json.dumps({"scene": tiny_scene}).replace(
        '"MESH"', json.dumps(grid_mesh(230))).encode()
    gc.collect()
    assert len(body) > 5_000_000
    answer: dict = {}

    def submit() -> None:
        t0 = time.perf_counter()
        answer["status"] = post_raw(client, body).status_code
        answer["seconds"] = time.perf_counter() - t0

    submission = threading.Thread(target=submit)
    submission.start()
    latencies = []
    while submission.is_alive():
        t0 = time.perf_counter()
        assert client.get("/healthz").status_code == 200
        latencies.append(time.perf_counter() - t0)
        time.sleep(0.005)
    submission.join()
    assert answer["status"] == 201
    assert len(latencies) >= 5, latencies
    assert max(latencies) < 0.1 * answer["seconds"], (max(latencies), answer["seconds"])
