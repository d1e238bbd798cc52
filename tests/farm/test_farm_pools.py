"""Worker pools (tags) and the blocklist, with a Redis of this module's own, real worker nodes
(``celery worker`` processes, one pool process each) and the API in-process.

A Redis of its own: the session farm's node consumes Celery's default queue on the shared Redis
and would take (and skip, as another prefix's) the passes these tests send.
"""

from __future__ import annotations

import copy
import os
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.pools import parse_tags, queue_for, waiting_for, worker_queues
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, terminate, worker_command, worker_env
from tests.conftest import wait_until
from tests.farm.conftest import ROOT, farm_state, records_of

HERE = Path(__file__).resolve().parent
TIMEOUT = 120.0


def test_pool_queues_are_the_subsets_of_a_workers_tags():
    assert parse_tags(" gpu,bigmem ,gpu") == ("bigmem", "gpu")
    assert queue_for(()) == "celery"
    assert queue_for(["gpu", "bigmem"]) == queue_for(["bigmem", "gpu"]) == "lucent.pool.bigmem,gpu"
    assert worker_queues(["gpu", "bigmem"]) == [
        "celery", "lucent.pool.bigmem", "lucent.pool.gpu", "lucent.pool.bigmem,gpu"]
    # a job's queue is consumed exactly by the nodes that have all its tags
    for job in ([], ["gpu"], ["bigmem", "gpu"], ["gpu", "ssd"]):
        assert (queue_for(job) in worker_queues(["gpu", "bigmem"])) == \
            (set(job) <= {"gpu", "bigmem"})
    assert waiting_for(("gpu",), [frozenset(), frozenset({"bigmem"})]) == \
        "waiting for a worker with tags gpu"
    assert waiting_for(("gpu",), [frozenset({"gpu", "bigmem"})]) is None
    with pytest.raises(ValueError, match="tag 'GPU!'"):
        parse_tags("GPU!")
    with pytest.raises(ValueError, match="at most 5"):
        worker_queues(["a", "b", "c", "d", "e", "f"])


class Pool:
    """Worker nodes on this module's Redis and a test's key prefix, and the API on them."""

    def __init__(self, redis_url: str, tmp: Path):
        self.redis_url = redis_url
        self.prefix = f"lucent-pool-{uuid.uuid4().hex[:8]}"
        self.tmp = tmp
        self.settings = Settings(redis_url=redis_url, key_prefix=self.prefix, api_token=None,
                                 heartbeat_interval=0.25, sweep_interval=0.2,
                                 archive_done=False, **farm_state(self.prefix, tmp / "data"))
        self.procs: list[subprocess.Popen] = []

    def start(self, name: str, tags: str = "", app: str | None = None,
              **env: str) -> subprocess.Popen:
        cmd = worker_command(1, name=f"{name}-{self.prefix}@%h")
        extra = {"LUCENT_KEY_PREFIX": self.prefix, "LUCENT_HEARTBEAT_INTERVAL": "0.25",
                 "LUCENT_API_TOKEN": "", "LUCENT_WORKER_TAGS": tags,
                 "LUCENT_DATA_DIR": str(self.tmp / "data"), **env}
        if self.settings.database_schema:
            extra["LUCENT_DATABASE_SCHEMA"] = self.settings.database_schema
        if app:  # the test-only app in tests/farm
            cmd[cmd.index("worker.celery_app")] = app
            extra["PYTHONPATH"] = os.pathsep.join([str(HERE), str(ROOT)])
        log = open(self.tmp / f"{name}.log", "w")  # noqa: SIM115
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                env=worker_env(self.redis_url, 1, extra))
        log.close()
        self.procs.append(proc)
        return proc

    def wait_warm(self, api: TestClient, name: str) -> dict:
        """Until the node's pool process beats as idle; its /api/workers entry."""
        def warm():
            for p in self.procs:
                assert p.poll() is None, self.logs()
            return next((w for w in api.get("/api/workers").json()["data"]
                         if (w["node"] or "").startswith(f"{name}-") and w["state"] == "idle"),
                        None)
        return wait_until(warm, 240.0, f"node {name} warm", interval=0.1)  # type: ignore[return-value]

    def logs(self) -> str:
        return "\n".join(p.read_text()[-2000:] for p in sorted(self.tmp.glob("*.log")))

    def stop(self) -> None:
        for proc in self.procs:
            terminate(proc, 10.0)


@pytest.fixture(scope="module")
def pool_redis() -> Iterator[str]:
    server = EmbeddedRedis().start()
    yield server.url
    server.stop()


@pytest.fixture
def pool(pool_redis: str, tmp_path: Path) -> Iterator[Pool]:
    p = Pool(pool_redis, tmp_path)
    yield p
    p.stop()


def _scene(cornell: dict, spp: int = 4) -> dict:
    scene = copy.deepcopy(cornell)
    scene["film"] = {"width": 16, "height": 16}
    scene["render"]["spp"] = spp
    return scene


def _done(api: TestClient, job_id: str, timeout: float = TIMEOUT) -> dict:
    return wait_until(lambda: (j := api.get(f"/api/jobs/{job_id}").json())["status"]  # type: ignore[return-value]
                      in ("done", "failed", "cancelled") and j, timeout, f"job {job_id}")


def _tiles_done(api: TestClient, name: str) -> int:
    return sum(w["tiles_done"] for w in api.get("/api/workers").json()["data"]
               if (w["node"] or "").startswith(f"{name}-"))


@pytest.mark.slow
def test_a_job_requiring_a_tag_runs_only_on_workers_with_it(pool, cornell):
    scene = _scene(cornell)
    job = {"scene": scene, "tile_size": 8, "spp_per_pass": 2, "max_spp_per_pass": 2}
    with TestClient(create_app(pool.settings)) as api:
        pool.start("plain")
        plain = pool.wait_warm(api, "plain")
        assert plain["tags"] == []
        # No live worker has the tag: refused only when asked to check
        r = api.post("/api/jobs", json={**job, "tags": ["gpu"], "check_workers": True})
        assert r.status_code == 409, r.text
        assert r.json()["detail"][0]["loc"] == ["body", "tags"]
        assert "no live worker has the tags gpu" in r.json()["detail"][0]["msg"]
        r = api.post("/api/jobs", json={**job, "tags": ["gpu", "gpu"]})
        assert r.status_code == 201, r.text
        gpu_job = r.json()["id"]
        assert r.json()["tags"] == ["gpu"]
        for bad in (["GPU"], ["a" * 33], "gpu", [1]):
            assert api.post("/api/jobs", json={**job, "tags": bad}).status_code == 422
        # An untagged job runs on the plain node meanwhile; the tagged one waits, visibly
        plain_job = api.post("/api/jobs", json=job).json()["id"]
        assert _done(api, plain_job)["status"] == "done"
        waiting = api.get(f"/api/jobs/{gpu_job}").json()
        assert waiting["status"] == "queued" and waiting["tasks_merged"] == 0
        assert waiting["waiting_for"] == "waiting for a worker with tags gpu"
        listed = {j["id"]: j for j in api.get("/api/jobs").json()["data"]}
        assert listed[gpu_job]["waiting_for"] == "waiting for a worker with tags gpu"
        # A node with the tag (and another) comes: it takes the job
        pool.start("gpu", tags="gpu,bigmem")
        gpu = pool.wait_warm(api, "gpu")
        assert gpu["tags"] == ["bigmem", "gpu"]
        done = _done(api, gpu_job)
        assert done["status"] == "done" and done["waiting_for"] is None, done
        tasks = done["tasks_total"]
        wait_until(lambda: _tiles_done(api, "gpu") == tasks, 10, "the gpu node's heartbeat")
        assert _tiles_done(api, "plain") == tasks  # the untagged job's, none of the gpu job's
        # With a live node that has them, check_workers accepts
        r = api.post("/api/jobs", json={**job, "tags": ["gpu"], "check_workers": True})
        assert r.status_code == 201, r.text
        assert _done(api, r.json()["id"])["status"] == "done"
    assert records_of(pool.settings).get(gpu_job).tags == ("gpu",)


@pytest.mark.slow
def test_a_worker_failing_every_pass_of_a_job_is_blocklisted_and_the_job_completes(pool,
                                                                                   cornell):
    """A node whose every pass raises (``faulty_worker``, ``*:*:raise``) fails 3 passes of the
    job, is blocklisted for it and hands its passes back; the other node renders them all and the
    image is the local render's. With the good node gone, the next job fails, saying no eligible
    worker remains; deleting it removes its blocklist keys."""
    import io

    import numpy as np

    from renderer.render import render

    scene = _scene(cornell)
    job = {"scene": scene, "tile_size": 8, "spp_per_pass": 2, "max_spp_per_pass": 2}
    with TestClient(create_app(pool.settings)) as api:
        # 5 tries a pass: the bad node alone (3 failures at most) never spends them all, so the
        # job fails for want of a node, not of tries
        pool.start("bad", app="faulty_worker", LUCENT_TEST_FAULT="*:*:raise",
                   LUCENT_MAX_ATTEMPTS="5")
        good_proc = pool.start("good", LUCENT_MAX_ATTEMPTS="5")
        bad = pool.wait_warm(api, "bad")["node"]
        good = pool.wait_warm(api, "good")["node"]
        job_id = api.post("/api/jobs", json=job).json()["id"]
        done = _done(api, job_id)
        assert done["status"] == "done", done
        assert done["blocklist"] == {bad: 3}, done
        assert any(f"on {bad}" in e and "blocklisted" in e for e in done["errors"])
        assert _tiles_done(api, "bad") == 0
        image = np.load(io.BytesIO(api.get(f"/api/jobs/{job_id}/image.npy").content))
        np.testing.assert_allclose(image, render(scene), rtol=1e-5, atol=1e-7)
        # The good node leaves: the next job has no eligible worker once the bad one is out
        terminate(good_proc, 30.0)
        wait_until(lambda: all(w["node"] != good for w in api.get("/api/workers").json()["data"]
                               if w["state"] != "lost"), 20, "the good node gone")
        second = api.post("/api/jobs", json=job).json()["id"]
        failed = _done(api, second)
        assert failed["status"] == "failed", failed
        assert failed["error"].startswith("no eligible worker remains: every live worker node "
                                          "is blocklisted for this job after 3 failed passes"), \
            failed["error"]
        assert bad in failed["error"] and failed["blocklist"] == {bad: 3}
        store = JobStore(redis.Redis.from_url(pool.redis_url), pool.prefix)
        keys = [store.k("job", second, "failures"), store.k("job", second, "blocklist")]
        assert store.r.exists(*keys) == 2
        assert api.delete(f"/api/jobs/{second}").status_code == 204
        assert store.r.exists(*keys) == 0
