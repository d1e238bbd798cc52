"""Jobs of frames: JSON Patch (RFC 6902) per frame, validated before acceptance, interleaved in
the queue, rendered on the session farm's real workers and compared with ``lucent render``."""

from __future__ import annotations

import copy
import io
import json
import time

import numpy as np
import pytest

from services.cli import main as lucent
from services.farm.frames import PatchError, apply_patch, pointer, sweep_patches
from services.farm.planner import Plan

# --- JSON Patch ----------------------------------------------------------------------------------

# RFC 6902, appendix A (a selection): document, patch, result.
RFC_EXAMPLES = [
    ({"foo": "bar"}, [{"op": "add", "path": "/baz", "value": "qux"}],
     {"baz": "qux", "foo": "bar"}),
    ({"foo": ["bar", "baz"]}, [{"op": "add", "path": "/foo/1", "value": "qux"}],
     {"foo": ["bar", "qux", "baz"]}),
    ({"baz": "qux", "foo": "bar"}, [{"op": "remove", "path": "/baz"}], {"foo": "bar"}),
    ({"foo": ["bar", "qux", "baz"]}, [{"op": "remove", "path": "/foo/1"}],
     {"foo": ["bar", "baz"]}),
    ({"baz": "qux", "foo": "bar"}, [{"op": "replace", "path": "/baz", "value": "boo"}],
     {"baz": "boo", "foo": "bar"}),
    ({"foo": {"bar": "baz", "waldo": "fred"}, "qux": {"corge": "grault"}},
     [{"op": "move", "from": "/foo/waldo", "path": "/qux/thud"}],
     {"foo": {"bar": "baz"}, "qux": {"corge": "grault", "thud": "fred"}}),
    ({"foo": ["all", "grass", "cows", "eat"]}, [{"op": "move", "from": "/foo/1", "path": "/foo/3"}],
     {"foo": ["all", "cows", "eat", "grass"]}),
    ({"foo": ["bar"]}, [{"op": "add", "path": "/foo/-", "value": ["abc", "def"]}],
     {"foo": ["bar", ["abc", "def"]]}),
    ({"/": 9, "~1": 10}, [{"op": "test", "path": "/~01", "value": 10}], {"/": 9, "~1": 10}),
    ({"foo": 1}, [{"op": "copy", "from": "/foo", "path": "/bar"}], {"foo": 1, "bar": 1}),
]


@pytest.mark.parametrize(("doc", "patch", "result"), RFC_EXAMPLES)
def test_json_patch_follows_rfc_6902s_examples(doc, patch, result):
    before = copy.deepcopy(doc)
    assert apply_patch(doc, patch) == result
    assert doc == before  # a new document: the job's scene is never changed in place


@pytest.mark.parametrize(("patch", "field", "words"), [
    ([{"op": "add", "path": "/baz/bat", "value": "qux"}], "path", "/baz/bat does not exist"),
    ([{"op": "replace", "path": "/nope", "value": 1}], "path", "/nope does not exist"),
    ([{"op": "remove", "path": "/foo/01"}], "path", "not an array index"),
    ([{"op": "add", "path": "/foo/5", "value": 1}], "path", "past the end"),
    ([{"op": "test", "path": "/n", "value": True}], "value", "test failed"),  # 1 is not true
    ([{"op": "move", "from": "/a", "path": "/a/b"}], "from", "own child"),
    ([{"op": "frobnicate", "path": "/a"}], "op", "must be one of"),
    ([{"op": "add", "path": "/a"}], "value", "'value' is required"),
    ([{"op": "add", "path": "a", "value": 1}], "path", "not a JSON Pointer"),
    ([{"op": "remove", "path": "/a", "value": 1}], "value", "unknown member"),
])
def test_a_bad_patch_names_the_operation_and_field(patch, field, words):
    with pytest.raises(PatchError, match=words) as err:
        apply_patch({"foo": ["x"], "a": {"b": 1}, "n": 1}, [{"op": "test", "path": "", "value":
                                                             {"foo": ["x"], "a": {"b": 1},
                                                              "n": 1}}, *patch])
    assert (err.value.index, err.value.field) == (1, field)


def test_sweep_patches_replace_one_field_a_frame():
    assert pointer("materials.wax/x.density") == "/materials/wax~1x/density"
    assert sweep_patches("materials.wax.density", [1, 2]) == [
        [{"op": "replace", "path": "/materials/wax/density", "value": 1}],
        [{"op": "replace", "path": "/materials/wax/density", "value": 2}]]


def test_the_order_gives_every_frame_a_coarse_pass_first():
    plan = Plan(64, 32, 32, 32, 8, 16, frames=3)
    assert plan.tiles_per_frame == 2 and plan.n_tiles == 6 and plan.n_passes == 3
    order = plan.order()
    assert len(order) == len(set(order)) == plan.n_tasks == 18
    # pass 0 of every tile of every frame before any pass 1, frame by frame
    assert [p for _, p in order[:6]] == [0] * 6
    assert [plan.frame_of(t) for t, _ in order[:6]] == [0, 0, 1, 1, 2, 2]
    assert plan.tile_rect(3) == plan.tile_rect(1) == (32, 0, 32, 32)


# --- on the farm ---------------------------------------------------------------------------------


def _frames() -> list[list[dict]]:
    """Three frames: as is; the camera moved; the camera moved and the white walls dimmed."""
    return [
        [],
        [{"op": "replace", "path": "/camera/position/0", "value": 0.4}],
        [{"op": "replace", "path": "/camera/position/0", "value": -0.4},
         {"op": "replace", "path": "/materials/white/albedo", "value": [0.3, 0.3, 0.3]}],
    ]


def test_a_three_frame_job_equals_three_lucent_renders_bit_for_bit(farm, farm_client,
                                                                    wait_for_job, tiny_scene,
                                                                    tmp_path):
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 24, "height": 16}
    scene["render"]["spp"] = 4
    frames = _frames()
    # one pass a tile: each pixel's samples summed in the order lucent render sums them
    r = farm_client.post("/api/jobs", json={"scene": scene, "frames": frames, "tile_size": 16,
                                            "spp_per_pass": 4})
    assert r.status_code == 201, r.text
    submitted = r.json()
    assert submitted["frames"] == 3 and submitted["tiles"] == 6
    assert submitted["samples_planned"] == 3 * 24 * 16 * 4
    job = wait_for_job(farm_client, submitted["id"])
    assert job["status"] == "done", job
    assert [f["progress"] for f in job["frame_progress"]] == [1.0, 1.0, 1.0]
    assert [t["frame"] for t in job["tile_states"]] == [0, 0, 1, 1, 2, 2]
    images = []
    for i, patch in enumerate(frames):
        path = tmp_path / f"frame{i}.json"
        path.write_text(json.dumps(apply_patch(scene, patch)))
        assert lucent(["render", str(path), "-o", str(tmp_path / f"frame{i}.npy"), "-q"]) == 0
        local = np.load(tmp_path / f"frame{i}.npy")
        got = farm_client.get(f"/api/jobs/{job['id']}/frames/{i}/image.npy")
        assert got.status_code == 200
        image = np.load(io.BytesIO(got.content))
        assert np.array_equal(image, local), f"frame {i} differs from lucent render"
        images.append(image)
    # the patches changed the frames
    assert not any(np.array_equal(images[a], images[b]) for a, b in ((0, 1), (0, 2), (1, 2)))
    first = np.load(io.BytesIO(farm_client.get(f"/api/jobs/{job['id']}/image.npy").content))
    assert np.array_equal(first, images[0])
    assert farm_client.get(f"/api/jobs/{job['id']}/frames/3/image.png").status_code == 404
    png = farm_client.get(f"/api/jobs/{job['id']}/frames/2/image.png")
    assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    # not left done in the session farm's Redis for another test's API to archive
    assert farm_client.delete(f"/api/jobs/{job['id']}").status_code == 204


def test_a_bad_frame_is_422_naming_the_frame_and_the_patch_path(farm_client, tiny_scene):
    frames = [[], [{"op": "replace", "path": "/materials/nope/albedo", "value": [1, 1, 1]}],
              [{"op": "replace", "path": "/render/max_depth", "value": "deep"}],
              [{"op": "replace", "path": "/film/width", "value": 64}], "not a patch"]
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "frames": frames[:4]})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    by_loc = {tuple(d["loc"]): d["msg"] for d in detail}
    assert by_loc[("body", "frames", 1, 0, "path")].startswith(
        "frame 1: operation 0: path /materials/nope/albedo does not exist")
    assert by_loc[("body", "frames", 2, "scene", "render", "max_depth")].startswith("frame 2: ")
    assert "keeps the scene's film size and spp" in by_loc[("body", "frames", 3)]
    assert len(detail) == 3  # frame 0, an empty patch, is the scene itself
    # not a list of operations: the request's own validation names the frame
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "frames": frames[4:]})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:3] == ["body", "frames", 0]


def test_the_cost_limits_count_every_frame(store, settings):
    from services.farm.cost import check_cost

    limited = settings.model_copy(update={"max_samples_per_job": 2 * 24 * 16 * 4})
    assert check_cost(Plan(24, 16, 4, 16, 4, frames=2), store, limited) is None
    refused = check_cost(Plan(24, 16, 4, 16, 4, frames=3), store, limited)
    assert refused is not None and refused.status == 422
    assert "24 x 16 pixels x 4 spp x 3 frames = 4608 pixel-samples exceed" in refused.msg


def test_an_archived_job_of_frames_serves_each_frame_and_deletes_them_all(farm, tiny_scene,
                                                                          tmp_path,
                                                                          wait_for_job):
    """Done, the job leaves Redis: each frame's EXR and PNG go to the blob store, named in its
    record; the frame routes serve them (the local render's image), and deleting the job
    removes every one of those blobs."""
    import random

    from fastapi.testclient import TestClient

    from renderer.render import render
    from services.api.main import create_app
    from services.farm.blobs import FileBlobStore
    from tests.conftest import wait_until
    from tests.farm.conftest import records_of

    settings = farm.settings.model_copy(update={"data_dir": tmp_path})
    records = records_of(settings)
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 16, "height": 16}
    scene["render"].update(spp=8, seed=random.randrange(1, 2**31))
    frames = _frames()
    with TestClient(create_app(settings)) as client:
        job_id = client.post("/api/jobs", json={"scene": scene, "frames": frames}).json()["id"]
        assert wait_for_job(client, job_id)["status"] == "done"
        wait_until(lambda: (r := records.get(job_id)) is not None and bool(r.images), 30,
                   "the job archived")
        record = records.get(job_id)
        assert record.plan.frames == 3 and len(record.tiles_final["frame_images"]) == 3
        for i, patch in enumerate(frames):
            got = client.get(f"/api/jobs/{job_id}/frames/{i}/image.npy")
            assert got.status_code == 200, got.text
            np.testing.assert_allclose(np.load(io.BytesIO(got.content)),
                                       render(apply_patch(scene, patch)), rtol=1e-5, atol=1e-7)
        job = client.get(f"/api/jobs/{job_id}").json()
        assert job["frames"] == 3 and [f["progress"] for f in job["frame_progress"]] == [1.0] * 3
        keys = {k for images in record.tiles_final["frame_images"] for k in images.values()}
        assert len(keys) == 6
        assert client.delete(f"/api/jobs/{job_id}").status_code == 204
        # (only this job's: the session's records on PostgreSQL are shared, and this API's
        # sweeper archives other tests' done jobs into its blob folder too)
        blobs = FileBlobStore(settings.blob_path)
        assert not [k for k in keys if blobs.exists(k)]


def test_lucent_submit_sweep_writes_a_numbered_file_a_frame(farm, farm_client, tiny_scene,
                                                            tmp_path, monkeypatch, capsys):
    """``lucent submit --sweep render.seed=1,2,3 -o out.npy``: one frame a value, and
    out_0000.npy ... out_0002.npy, each the local render of its scene."""
    import services.client
    from renderer.render import render
    from services.client import sweep_values

    assert sweep_values("1,2.5") == [1, 2.5]
    assert sweep_values("[1,0,0],[0,1,0]") == [[1, 0, 0], [0, 1, 0]]
    assert sweep_values("diffusion, volumetric") == ["diffusion", "volumetric"]

    class TestServerClient(services.client.Client):
        def __init__(self, server, token=None, **kw):
            super().__init__(server, token, **kw)
            self.http = farm_client  # the farm's API in this process

    monkeypatch.setattr(services.client, "Client", TestServerClient)
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 16, "height": 8}
    scene["render"]["spp"] = 4
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    out = tmp_path / "out" / "sweep.npy"
    assert lucent(["submit", str(tmp_path / "scene.json"), "--server", "http://testserver",
                   "--sweep", "render.seed=1,2,3", "-o", str(out), "-q"]) == 0
    written = sorted(p.name for p in out.parent.iterdir())
    assert written == ["sweep_0000.npy", "sweep_0001.npy", "sweep_0002.npy"]
    for seed, name in zip((1, 2, 3), written, strict=True):
        np.testing.assert_allclose(np.load(out.parent / name),
                                   render({**scene, "render": {**scene["render"], "seed": seed}}),
                                   rtol=1e-5, atol=1e-7)
    job_id = capsys.readouterr().out.strip().splitlines()[-1]
    assert farm_client.delete(f"/api/jobs/{job_id}").status_code == 204
    assert lucent(["submit", str(tmp_path / "scene.json"), "--sweep", "render.seed"]) == 2


def test_a_target_jobs_bias_is_its_frames_largest():
    """check_scene keeps, for a job with a target, the bias auto's models may add over the frame
    (renderer.materials.auto.frame_bias), the largest over its frames: a frame whose camera
    comes close to dense wax (rendered as the opaque surface) raises it; without a target, none."""
    from pathlib import Path

    from renderer.materials.auto import frame_bias
    from renderer.scene import Limits, load_scene
    from services.farm.jobs import check_scene

    root = Path(__file__).resolve().parents[2]
    scene = json.loads((root / "examples" / "translucent_sphere.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["materials"]["wax"].update(method="auto", albedo=[0.99] * 3, g=0.5, density=3000.0)
    scene["render"]["target_error"] = 0.01
    frames = [[], [{"op": "replace", "path": "/camera/position", "value": [0.0, -0.5, 1.3]},
                   {"op": "replace", "path": "/camera/look_at", "value": [0.0, -0.5, 0.0]}]]
    far = frame_bias(load_scene(scene))
    near = frame_bias(load_scene(apply_patch(scene, frames[1])))
    assert 0 < far < near
    assert check_scene(scene, Limits()).expected_bias == pytest.approx(far, rel=1e-12)
    assert check_scene(scene, Limits(), frames=frames).expected_bias == pytest.approx(near,
                                                                                     rel=1e-12)
    scene["render"].pop("target_error")
    assert check_scene(scene, Limits(), frames=frames).expected_bias == 0.0


def test_a_target_job_of_frames_keeps_each_frames_sums_only_where_every_live_worker_does(
        client, store, tiny_scene, wait_until):
    """A farm upgraded worker by worker: a worker from before merge protocols (its heartbeat
    gives none) merges a target job of frames without the frames' own sums, and a job stored
    with them would wait for sums it never writes. So a target job of frames keeps each frame's
    sums where no live worker's merge is older than ``FRAME_SUMS_PROTOCOL`` (no worker live:
    those to come are this code's), and pools them, as every worker's merge keeps, while one is
    live; /api/workers says each worker's protocol and release. Seen failing with the sums kept
    whatever the workers."""
    from services.farm.store import FRAME_SUMS_PROTOCOL, MERGE_PROTOCOL

    scene = copy.deepcopy(tiny_scene)
    scene["render"]["target_error"] = 0.05
    frames = [[], [{"op": "add", "path": "/render/seed", "value": 2}]]

    def stored(body: dict) -> bool:
        r = client.post("/api/jobs", json=body)
        assert r.status_code in (201, 202), r.text
        return store.get_job(r.json()["id"]).frame_sums

    assert stored({"scene": scene, "frames": frames})
    store.heartbeat("new@a", {"host": "a", "pid": 1, "state": "idle",
                              "protocol": MERGE_PROTOCOL, "version": "0.1.0"}, ttl=60)
    assert MERGE_PROTOCOL >= FRAME_SUMS_PROTOCOL and stored({"scene": scene, "frames": frames})
    store.heartbeat("old@b", {"host": "b", "pid": 2, "state": "idle"}, ttl=60)
    assert not stored({"scene": scene, "frames": frames})
    # (only the workers that take the job count: the old one has not its tags)
    assert stored({"scene": scene, "frames": frames, "tags": ["bigmem"]})
    workers = {w["id"]: w for w in client.get("/api/workers").json()["data"]}
    assert (workers["new@a"]["protocol"], workers["new@a"]["version"]) == (MERGE_PROTOCOL,
                                                                           "0.1.0")
    assert (workers["old@b"]["protocol"], workers["old@b"]["version"]) == (1, None)
    # ... and /metrics counts the live ones by release, kernel and protocol
    metrics = client.get("/metrics").text
    assert 'lucent_worker_releases{version="0.1.0",kernel="",protocol="2"} 1' in metrics
    assert 'lucent_worker_releases{version="",kernel="",protocol="1"} 1' in metrics
    store.heartbeat("odd@c", {"host": "c", "pid": 3, "state": 'id"le', "protocol": 2,
                              "version": 'x"y\\z\nw'}, ttl=60)
    metrics = client.get("/metrics").text  # (a label's quote, backslash and newline escaped)
    assert 'lucent_worker_releases{version="x\\"y\\\\z\\nw",kernel="",protocol="2"} 1' in metrics
    assert 'lucent_workers{state="id\\"le"} 1' in metrics
    store.remove_worker("odd@c")
    # (a job of one frame, or without a target, keeps no frames' sums either way)
    assert not stored({"scene": scene})
    store.remove_worker("old@b")
    # (a sweep of the API's that read the old worker live may still be pooling: let it end)
    time.sleep(0.5)
    assert stored({"scene": scene, "frames": frames})
    # an old worker whose heartbeat expired is no longer live: it merges nothing
    store.r.zadd(store.k("workers"), {"gone@c": time.time() - 30})
    assert stored({"scene": scene, "frames": frames})
    assert next(w for w in client.get("/api/workers").json()["data"]
                if w["id"] == "gone@c")["protocol"] is None
    # An old worker that joins after such a job was stored: the API's sweeper pools its sums
    # (pool_frames_beside_old_workers, below)
    r = client.post("/api/jobs", json={"scene": scene, "frames": frames})
    assert store.get_job(r.json()["id"]).frame_sums
    store.heartbeat("old@b", {"host": "b", "pid": 2, "state": "idle"}, ttl=60)
    wait_until(lambda: not store.get_job(r.json()["id"]).frame_sums, 10.0, "the sums pooled")


def test_an_old_worker_that_joins_a_target_job_of_frames_makes_it_pool_its_sums(
        store, monkeypatch):
    """A target job of frames stored with each frame's sums, then a worker from before merge
    protocols joins: its merges would leave the frames' sums short (each merge adds a tile's
    change to them), so the sweeper's ``pool_frames_beside_old_workers`` makes the job pool
    them (the job's own sums, which every merge keeps) and asks its converged tiles again on
    those, job-wide. Not a job that worker does not take (its tags), nor one pooled already;
    a merge after it keeps no frames' sums. Seen failing with the job left as it was."""
    import numpy as np

    from renderer.film.buffer import SampleBuffer
    from services.farm import queue

    plan = Plan(16, 16, 64, 16, 8, 0, 2)  # 2 frames of one 16x16 tile
    jobs = {name: f"{i:032x}" for i, name in enumerate(("plain", "gpu", "untargeted"), 1)}
    store.create_job(jobs["plain"], "", 0, plan, b"{}", {}, time.time(), target_error=0.05)
    store.create_job(jobs["gpu"], "", 0, plan, b"{}", {}, time.time(), tags=("gpu",),
                     target_error=0.05)
    store.create_job(jobs["untargeted"], "", 0, plan, b"{}", {}, time.time())
    woken: list[str] = []
    monkeypatch.setattr(queue, "wake_converged",
                        lambda st, send, job_id, **kw: woken.append(job_id) or [])
    store.heartbeat("new@a", {"host": "a", "pid": 1, "state": "idle", "protocol": 2}, ttl=60)
    assert queue.pool_frames_beside_old_workers(store, None) == []
    store.heartbeat("old@b", {"host": "b", "pid": 2, "state": "idle"}, ttl=60)
    assert queue.pool_frames_beside_old_workers(store, None) == [jobs["plain"]]
    assert woken == [jobs["plain"]]
    assert not store.get_job(jobs["plain"]).frame_sums
    assert store.get_job(jobs["gpu"]).frame_sums  # (the old worker has not its tag)
    assert queue.pool_frames_beside_old_workers(store, None) == []  # (once)
    # a merge after it keeps the job's sums, not the frames'
    buf = SampleBuffer.empty(*plan.tile_rect(1))
    x = np.random.default_rng(5).exponential(1.0, (4, 16, 16, 3))
    buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), 4
    store.put_pass(jobs["plain"], 1, 0, buf.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(jobs["plain"], 1, 0)
    assert not store.r.exists(store.k("job", jobs["plain"], "frame_sums"))
    assert store.get_job(jobs["plain"]).look_pixels == 256
    store.put_pass(jobs["gpu"], 1, 0, buf.to_bytes(), ttl=60)
    assert store.merge_pass_buffer(jobs["gpu"], 1, 0)
    assert store.r.exists(store.k("job", jobs["gpu"], "frame_sums"))
