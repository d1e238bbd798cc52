"""The farm end to end: real Redis, real Celery worker processes, the API in-process."""

from __future__ import annotations

import copy
import io
import json
import os
import signal
import uuid
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from renderer.film.adaptive import AIM, error_terms
from renderer.film.buffer import SampleBuffer
from renderer.render import render
from services.api.main import create_app
from services.farm.merge import assemble
from services.farm.planner import Plan
from services.farm.queue import enqueue

# As long as the farm fixture waits for its first warm processes (conftest.WORKER_START_TIMEOUT).
POOL_RECOVERY_TIMEOUT = 240.0


def _image(client, job_id) -> np.ndarray:
    r = client.get(f"/api/jobs/{job_id}/image.npy")
    assert r.status_code == 200
    return np.load(io.BytesIO(r.content))


def _live(client) -> list[dict]:
    workers = client.get("/api/workers").json()["data"]
    return [w for w in workers if w["state"] in ("idle", "busy")]


def _assert_complete(farm, job_id, scene, image):
    """Every pixel holds exactly spp samples, and the image is the local render's."""
    store = farm.store()
    frame, _ = assemble(store, job_id)
    assert (frame.count + frame.dropped == scene["render"]["spp"]).all()
    assert store.r.scard(store.k("pending")) == 0
    np.testing.assert_allclose(image, render(scene), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize(("tile_size", "spp_per_pass"), [(16, 8), (10, 3)])
def test_job_equals_the_local_render(farm, farm_client, wait_for_job, tiny_scene, tile_size,
                                     spp_per_pass):
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": tile_size,
                                            "spp_per_pass": spp_per_pass})
    assert r.status_code == 201, r.text
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done", job
    assert job["progress"] == 1.0 and job["tasks_merged"] == job["tasks_total"]
    assert {t["state"] for t in job["tile_states"]} == {"done"}
    assert {t["samples"] for t in job["tile_states"]} == {16}
    _assert_complete(farm, job["id"], tiny_scene, _image(farm_client, job["id"]))
    # A job without a target reports its estimated error too: each tile's, the mean of its
    # merged buffer's error terms (its summary kept over several merges, as its whole), and
    # over the frame's pixels they make the job's
    store = farm.store()
    assert job["target_error"] is None
    for t in job["tile_states"]:
        terms = error_terms(SampleBuffer.from_bytes(store.tile_buffer(job["id"], t["index"])))
        assert t["expected_error"] == pytest.approx(terms.mean(), rel=1e-9)
    pixels = sum(t["width"] * t["height"] for t in job["tile_states"])
    assert job["expected_error"] == pytest.approx(sum(
        t["expected_error"] * t["width"] * t["height"] for t in job["tile_states"]) / pixels,
        rel=1e-9)
    # ETag: a poller gets 304 while nothing changes.
    png = farm_client.get(f"/api/jobs/{job['id']}/image.png")
    assert png.headers["content-type"] == "image/png" and png.content[:4] == b"\x89PNG"
    again = farm_client.get(f"/api/jobs/{job['id']}/image.png",
                            headers={"If-None-Match": png.headers["etag"]})
    assert again.status_code == 304
    assert farm_client.get(f"/api/jobs/{job['id']}/image.exr").content[:4] == b"\x76\x2f\x31\x01"


def test_a_job_whose_every_sample_is_dropped_fails_with_the_reason(farm_client, wait_for_job,
                                                                  tiny_scene):
    """A background of 1e308 is a valid number, but it lights a sphere with infinite power: each
    sample is dropped as non-finite. The job ended "done" with a black image; it fails, saying
    why. (In the Cornell box, 80 % of the samples are dropped: the paths that never meet the
    background are kept.)"""
    tiny_scene["background"] = [1e308, 1e308, 1e308]
    tiny_scene["objects"] = [{"type": "sphere", "center": [0, 0, 0], "radius": 0.5,
                              "material": "white"}]
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "spp_per_pass": 16})
    assert r.status_code == 201, r.text
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "failed", job
    assert job["error"].startswith("every sample (12288) was dropped"), job["error"]
    assert job["errors"] == [job["error"]]
    assert job["dropped_samples"] == 12288 and job["tasks_merged"] == job["tasks_total"]


def test_a_task_delivered_twice_is_merged_once(farm, farm_client, wait_for_job, tiny_scene):
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": 16,
                                            "spp_per_pass": 4})
    job_id = r.json()["id"]
    # Every (tile, pass) delivered a second time, as Redis does after a visibility timeout.
    plan = farm.store().get_job(job_id).plan
    # (the largest pass the packet kernel's default: the Cornell box is a scene it covers)
    assert plan == Plan(32, 24, 16, 16, 4, 256, pass_growth=2) and plan.n_passes == 3  # 4, 8, 4
    enqueue(farm_client.app.state.celery, job_id, plan.order(), 0)
    job = wait_for_job(farm_client, job_id)
    assert job["status"] == "done"
    assert job["tasks_merged"] == plan.n_tasks
    _assert_complete(farm, job_id, tiny_scene, _image(farm_client, job_id))


def test_a_message_for_a_pass_outside_the_plan_is_skipped(farm, farm_client, wait_for_job,
                                                          tiny_scene):
    """Messages naming passes the job's plan does not have (the equal passes of an older plan)
    render nothing, spend no try and fail no tile: the job completes exactly as planned."""
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": 16,
                                            "spp_per_pass": 4})
    job_id = r.json()["id"]
    stale = [(t, p) for t, p in Plan(32, 24, 16, 16, 4).order() if p >= 3] + [(99, 0)]
    # At the most urgent priority, so that they are taken before the job's own last passes.
    enqueue(farm_client.app.state.celery, job_id, stale, 9)
    job = wait_for_job(farm_client, job_id)
    assert job["status"] == "done", job
    assert job["tasks_merged"] == job["tasks_total"] == 4 * 3  # 2 x 2 tiles, 4 + 8 + 4 spp
    assert all(t["error"] is None for t in job["tile_states"])
    _assert_complete(farm, job_id, tiny_scene, _image(farm_client, job_id))


def test_cancel_mid_job(farm, farm_client, wait_for_job, wait_until, tiny_scene):
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 64, "height": 48}
    scene["render"]["spp"] = 1024
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 16, "spp_per_pass": 2})
    job_id = r.json()["id"]
    wait_until(lambda: farm_client.get(f"/api/jobs/{job_id}").json()["tasks_merged"] > 0,
               120, "the first merged pass")
    assert farm_client.delete(f"/api/jobs/{job_id}").json()["status"] == "cancelled"
    job = wait_for_job(farm_client, job_id, statuses=("cancelled",))
    merged = job["tasks_merged"]
    assert merged < job["tasks_total"]
    # The queue drains quickly (cancelled tasks do nothing) and nothing more is merged after at
    # most the passes that were running.
    store = farm.store()
    wait_until(lambda: store.r.llen("celery") == 0, 60, "the queue to drain", interval=0.2)
    wait_until(lambda: not [w for w in store.workers() if w.get("state") == "busy"], 30,
               "idle workers", interval=0.2)
    assert farm_client.get(f"/api/jobs/{job_id}").json()["tasks_merged"] <= merged + 2
    assert _image(farm_client, job_id).any()  # the partial image stays available


def test_worker_process_killed_mid_job(farm, farm_client, wait_for_job, wait_until, tiny_scene):
    psutil = pytest.importorskip("psutil")
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 48, "height": 32}
    scene["render"]["spp"] = 256
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 16, "spp_per_pass": 4})
    job_id = r.json()["id"]
    wait_until(lambda: farm_client.get(f"/api/jobs/{job_id}").json()["tasks_merged"] > 4,
               120, "passes merging")
    children = psutil.Process(farm.proc.pid).children()
    assert children, "no pool processes"
    for child in children:  # both pool processes, mid-task: SIGKILL, as the OOM killer would
        os.kill(child.pid, signal.SIGKILL)
    job = wait_for_job(farm_client, job_id)
    assert job["status"] == "done", job
    assert farm.proc.poll() is None
    _assert_complete(farm, job_id, scene, _image(farm_client, job_id))
    # The pool replaces both processes; the replacements warm up and report themselves (the
    # next tests need two live processes again: warm-up after a fork takes seconds on a busy CI).
    wait_until(lambda: len(_live(farm_client)) >= 2, POOL_RECOVERY_TIMEOUT,
               "two replacement pool processes to report idle")


def test_service_restarted_mid_job(farm, wait_for_job, wait_until, tiny_scene):
    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 48, "height": 32}
    scene["render"]["spp"] = 512
    # done jobs keep their accumulations (as farm_client's): _assert_complete reads them
    settings = farm.settings.model_copy(update={"archive_done": False})
    with TestClient(create_app(settings)) as first:
        # 6 tiles x 33 passes of at most 16 samples: many short tasks, still running when the
        # first service stops
        job_id = first.post("/api/jobs", json={"scene": scene, "tile_size": 16,
                                               "spp_per_pass": 4,
                                               "max_spp_per_pass": 16}).json()["id"]
        wait_until(lambda: first.get(f"/api/jobs/{job_id}").json()["tasks_merged"] > 0, 120,
                   "passes merging")
    # The service is gone (its sweeper stopped); a new one carries on from Redis.
    with TestClient(create_app(settings)) as second:
        job = wait_for_job(second, job_id)
        assert job["status"] == "done"
        _assert_complete(farm, job_id, scene, _image(second, job_id))


def test_a_poison_scene_fails_the_job_not_the_worker(farm, farm_client, wait_for_job,
                                                      tiny_scene):
    """A job whose stored scene a worker cannot load (here: written into Redis behind the API's
    back, as a bug or a tampered store could) fails with the reason after no retries loop, and
    the workers go on rendering."""
    bad = copy.deepcopy(tiny_scene)
    bad["objects"][0]["edge1"] = [0, 0, 0]  # degenerate quad: refused by load_scene
    store = farm.store()
    plan = Plan(32, 24, 16, 16, 8)
    poison = uuid.uuid4().hex  # an id of the API's form
    store.create_job(poison, "poison", 0, plan, json.dumps(bad))
    enqueue(farm_client.app.state.celery, poison, plan.order(), 0)
    job = wait_for_job(farm_client, poison)
    assert job["status"] == "failed"
    assert "objects[0]" in job["error"]
    assert farm.proc.poll() is None
    # The workers still render.
    ok = farm_client.post("/api/jobs", json={"scene": tiny_scene}).json()
    assert wait_for_job(farm_client, ok["id"])["status"] == "done"


def test_workers_report_heartbeats(farm, farm_client, wait_until):
    """Both pool processes report host, pid and a heartbeat. Bounded wait: a process replaced by
    an earlier test (SIGKILL) reports "starting" until its JIT warm-up is done."""
    live = wait_until(lambda: (lambda ws: ws if len(ws) >= 2 else None)(_live(farm_client)),
                      POOL_RECOVERY_TIMEOUT, "two live pool processes")
    assert all(w["host"] and w["pid"] and w["last_heartbeat"] for w in live)


def test_a_target_job_runs_a_chain_of_passes_per_tile_not_every_planned_pass(
        farm, farm_client, wait_for_job, tiny_scene):
    """A job with a target error and room for many passes (4096 spp in passes of 16: 256 a
    tile) queues only each tile's first pass; a pass that merges queues the tile's next, and the
    first that finds the tile converged counts the rest as merged. So the workers run a few
    passes a tile, not 256, and the job still completes its planned task count."""
    scene = copy.deepcopy(tiny_scene)
    scene["render"].update(spp=4096, target_error=0.02)
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 8, "spp_per_pass": 8,
                                            "max_spp_per_pass": 16})
    assert r.status_code == 201, r.text
    planned = r.json()
    assert planned["passes"] == 257  # 8, 8, then 255 of 16 (4096 − 16 = 255 × 16 + 16)
    job = wait_for_job(farm_client, planned["id"])
    assert job["status"] == "done", job
    assert job["tasks_merged"] == job["tasks_total"] == 257 * planned["tiles"]
    store = farm.store()
    ran = sum(int(v) for v in store.r.hvals(store.k("job", job["id"], "attempts")))
    # Each tile: the pilot, the passes that add samples, one that finds it converged
    assert planned["tiles"] * 2 <= ran <= planned["tiles"] * 40, ran
    frame, _ = assemble(store, job["id"])
    assert (frame.count + frame.dropped).max() < 4096
    assert 0 < job["expected_error"] <= 0.02
    assert job["progress"] == 1.0  # reached, at a small share of render.spp's samples
    # Archived (out of Redis, its record answers): the same target, error and progress
    from services.farm.archive import archive_job
    from services.farm.blobs import open_blob_store

    assert archive_job(store, farm.records(), open_blob_store(farm.settings.blob_location),
                       job["id"])
    after = farm_client.get(f"/api/jobs/{job['id']}").json()
    assert (after["target_error"], after["expected_error"], after["progress"]) == (
        0.02, job["expected_error"], 1.0)


@pytest.mark.slow
def test_target_jobs_never_wait_for_the_stall_rule(farm, farm_client, wait_for_job):
    """Target jobs whose tiles converge at about the same moment on two worker processes: the
    caustic floor at 64×48 and 0.1, tiles of 16 px, 24 seeds, each job a few tenths of a second,
    and each must end within 10 s, a third of the stall rule's 30 s
    (``LUCENT_STALL_UNHELD_TIMEOUT``), which re-sends the passes of an idle job. Seen failing
    with a converged tile requeued whatever it had become since it was read (7 of 33 such jobs
    took 30-31 s: a wake sent a tile's pass that had just merged, and left the tile marked
    queued with nothing in flight; ``JobStore.requeue_converged``)."""
    scene = json.loads((Path(__file__).parents[2] / "examples" / "caustic_floor.json")
                       .read_text())
    scene["film"] = {"width": 64, "height": 48}
    for seed in range(7, 31):
        scene["render"].update(spp=8192, target_error=0.1, seed=seed)
        r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 16})
        assert r.status_code == 201, r.text
        job = wait_for_job(farm_client, r.json()["id"], timeout=10.0)
        assert job["status"] == "done", job


def test_a_target_job_of_frames_takes_each_frame_to_the_target(farm, farm_client,
                                                               wait_for_job, tiny_scene):
    """A job of two frames with a target of 0.03, real workers: the diffuse Cornell box, then
    the glass sphere (a patch replacing the scene's fields), whose noise is several times the
    box's. Each frame ends with its own estimate within the rule's stop of the aim, the box on
    fewer samples a pixel than the sphere. With the frames' sums pooled, the job stopped on their
    mean: the sphere's frame ended above the target and the box's far below it."""
    from pathlib import Path

    from renderer.film.adaptive import STOP_SLACK
    from services.client import error_lines

    root = Path(__file__).resolve().parents[2]
    glass = json.loads((root / "examples" / "glass_sphere.json").read_text())
    box = copy.deepcopy(tiny_scene)
    for scene in (box, glass):
        scene["film"] = dict(tiny_scene["film"])
        scene["render"].update(spp=1024, target_error=0.03, seed=7)
    patch = ([{"op": "replace" if key in box else "add", "path": "/" + key, "value": value}
              for key, value in glass.items()]
             + [{"op": "remove", "path": "/" + key} for key in box if key not in glass])
    r = farm_client.post("/api/jobs", json={"scene": box, "frames": [[], patch],
                                            "tile_size": 16})
    assert r.status_code == 201, r.text
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done", job
    errors = [f["expected_error"] for f in job["frame_progress"]]
    assert all(0 < e <= AIM * 0.03 * (1.0 + STOP_SLACK) for e in errors), errors
    spp = [[t["samples"] for t in job["tile_states"] if t["frame"] == f] for f in (0, 1)]
    assert max(spp[0]) < min(spp[1]), spp
    # lucent submit --wait says each frame's
    lines = error_lines(job)
    assert [line.split(":")[0] for line in lines[1:]] == ["frame 0", "frame 1"], lines
    assert lines[0].startswith("expected relMSE") and ", the frames' mean (" in lines[0], lines
    assert not any("above the target" in line for line in lines), lines


def test_a_target_job_aims_the_noise_at_the_target_less_autos_bias(farm, farm_client,
                                                                   wait_for_job):
    """A close-up of dense wax that auto renders as the opaque surface, with a target of 0.01:
    the job keeps the bias the model may add over the frame (renderer.materials.auto.frame_bias,
    most of the target here), its workers stop where the samples' noise is within the rule's
    slack of AIM × (target − bias), and the job reports the noise and the bias together, within
    the target; its record keeps the bias once it leaves Redis."""
    from pathlib import Path

    from renderer.film.adaptive import STOP_SLACK
    from renderer.materials.auto import frame_bias
    from renderer.scene import load_scene
    from services.farm.archive import archive_job
    from services.farm.blobs import open_blob_store

    root = Path(__file__).resolve().parents[2]
    scene = json.loads((root / "examples" / "translucent_sphere.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["camera"].update(position=[0.0, -0.5, 1.3], look_at=[0.0, -0.5, 0.0])
    scene["materials"]["wax"].update(method="auto", albedo=[0.99] * 3, g=0.5, density=3000.0)
    scene["render"].update(spp=4096, target_error=0.01)
    bias = frame_bias(load_scene(scene))
    assert bias > 0.005
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 16, "spp_per_pass": 8,
                                            "max_spp_per_pass": 64})
    assert r.status_code == 201, r.text
    assert r.json()["methods"]["wax"].startswith("opaque")
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done", job
    assert job["expected_bias"] == pytest.approx(bias, rel=1e-12)
    noise = job["expected_error"] - bias
    assert 0 < noise <= AIM * (0.01 - bias) * (1.0 + STOP_SLACK)
    assert job["expected_error"] <= 0.01
    store = farm.store()
    assert archive_job(store, farm.records(), open_blob_store(farm.settings.blob_location),
                       job["id"])
    after = farm_client.get(f"/api/jobs/{job['id']}").json()
    assert (after["expected_bias"], after["expected_error"]) == (job["expected_bias"],
                                                                 job["expected_error"])


def test_a_target_jobs_first_pass_is_the_pilots_first_look(farm, farm_client, wait_for_job,
                                                            tiny_scene):
    """A job with a target renders FIRST_LOOK samples a pixel in a tile's first pass, as the
    local loop's first look, not the whole pass: the Cornell box (a packet scene, whose first
    pass is 32 samples by default) at a target its first look reaches stops with FIRST_LOOK
    samples in every pixel (it took 32, 0.07x the target, when the first pass was rendered
    whole; 8, the whole pilot, before the first look). At 64×48 in one tile: its pixels carry
    the estimate (on smaller tiles a few pixels at the light may, and the tile goes on)."""
    from renderer.film.adaptive import FIRST_LOOK

    scene = copy.deepcopy(tiny_scene)
    scene["film"] = {"width": 64, "height": 48}
    scene["render"].update(spp=256, target_error=0.5)
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 64})
    assert r.status_code == 201, r.text
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done" and job["spp_per_pass"] == 32, job
    frame, _ = assemble(farm.store(), job["id"])
    assert ((frame.count + frame.dropped) == FIRST_LOOK).all()
    assert job["expected_error"] <= AIM * 0.5


def test_adaptive_sampling_stops_converged_tiles(farm, farm_client, wait_for_job, tiny_scene):
    """With render.target_error, each pass renders only the pixels whose allocation lacks
    samples (renderer.film.adaptive.pass_counts on the tile's merged buffer, at the frame's scale
    from the tiles' summaries): the job completes as planned, the black border's tiles stop
    early while the noisy ones go on, no pixel has fewer than the pilot's first look, and the
    job's answer reports the target and the expected error it reached."""
    from renderer.film.adaptive import FIRST_LOOK

    scene = copy.deepcopy(tiny_scene)
    scene["render"].update(spp=256, target_error=0.02)
    r = farm_client.post("/api/jobs", json={"scene": scene, "tile_size": 8, "spp_per_pass": 8})
    assert r.status_code == 201, r.text
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done", job
    frame, _ = assemble(farm.store(), job["id"])
    samples = frame.count + frame.dropped
    assert samples.min() >= FIRST_LOOK
    assert samples.min() < 256 and samples.max() <= 256
    assert job["target_error"] == 0.02
    assert job["expected_error"] is not None and 0 < job["expected_error"] <= 0.02
    # Each tile's estimate is the mean of its pixels' error terms in its merged buffer
    # (renderer.film.adaptive.error_terms), and over the frame they make the job's
    store = farm.store()
    tiles = farm_client.get(f"/api/jobs/{job['id']}").json()["tile_states"]
    for t in tiles:
        terms = error_terms(SampleBuffer.from_bytes(store.tile_buffer(job["id"], t["index"])))
        assert t["expected_error"] == pytest.approx(terms.mean(), rel=1e-9)
    pixels = sum(t["width"] * t["height"] for t in tiles)
    assert sum(t["expected_error"] * t["width"] * t["height"] for t in tiles) / pixels == \
        pytest.approx(job["expected_error"], rel=1e-9)
