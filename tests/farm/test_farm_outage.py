"""Redis down: the API answers 503 with the kind of failure (never a 500, never Redis's address),
the probes say why the farm is not ready, and ``lucent submit``'s client waits through an outage
with backoff, saying why, instead of exiting on the first error.

Each test has its own embedded Redis, SIGKILLed (as the kernel's OOM killer would) and started
again on the same port and folder with ``appendonly yes``, so that the job comes back with it.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.client import RETRY_DELAYS, Client, Unavailable
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis

# Every operation of the OpenAPI document, with these path parameters.
EXAMPLE_PARAMS = {"fmt": "png", "name": "cornell_box", "frame": 0}


@pytest.fixture
def persistent_redis(tmp_path: Path) -> Iterator[EmbeddedRedis]:
    server = EmbeddedRedis(data_dir=str(tmp_path), appendonly=True).start()
    yield server
    server.stop()


@pytest.fixture
def outage_settings(persistent_redis: EmbeddedRedis) -> Settings:
    return Settings(redis_url=persistent_redis.url, key_prefix=f"lucent-outage-{uuid.uuid4().hex}",
                    api_token=None)


def _kill(server: EmbeddedRedis) -> None:
    assert server.proc is not None
    server.proc.kill()
    server.proc.wait()


def _operations(app, job_id: str) -> list[tuple[str, str]]:
    out = []
    for path, operations in app.openapi()["paths"].items():
        concrete = path.format(job_id=job_id, **EXAMPLE_PARAMS)
        out += [(method.upper(), concrete) for method in operations]
    return out


def test_redis_down_is_503_with_a_reason_on_every_route(persistent_redis, outage_settings,
                                                         tiny_scene):
    """With Redis SIGKILLed, every operation of the OpenAPI document answers without a 5xx other
    than 503; those that read the store (jobs, workers, metrics, readiness) answer 503 with
    ``Retry-After`` and a reason that names neither Redis's host nor its port. Once Redis is
    back, the same app answers 200 again without a restart."""
    with TestClient(create_app(outage_settings), raise_server_exceptions=False) as api:
        job_id = api.post("/api/jobs", json={"scene": tiny_scene}).json()["id"]
        _kill(persistent_redis)
        address = (str(persistent_redis.port), persistent_redis.host)
        answered: dict[tuple[str, str], int] = {}
        for method, path in _operations(api.app, job_id):
            body = {"scene": tiny_scene} if (method, path) == ("POST", "/api/jobs") else None
            r = api.request(method, path, json=body)
            answered[method, path] = r.status_code
            assert r.status_code < 500 or r.status_code == 503, (method, path, r.text)
            assert not any(part in r.text for part in address), (method, path, r.text)
            if r.status_code == 503 and path != "/readyz":
                assert r.headers["retry-after"] == "1", (method, path)
        for route in [("GET", "/api/jobs"), ("POST", "/api/jobs"), ("GET", f"/api/jobs/{job_id}"),
                      ("GET", f"/api/jobs/{job_id}/image.png"), ("DELETE", f"/api/jobs/{job_id}"),
                      ("POST", f"/api/jobs/{job_id}/retry"), ("GET", "/api/workers"),
                      ("GET", "/metrics")]:
            assert answered[route] == 503, route
        detail = api.get(f"/api/jobs/{job_id}").json()["detail"]
        assert detail == ("the farm's store is unavailable: Redis refused the connection (it is "
                          "not running); try again shortly")
        ready = api.get("/readyz")
        assert ready.status_code == 503
        assert ready.json() == {"status": "unavailable", "reasons": [detail]}
        assert api.get("/healthz").status_code == 200  # the process itself is fine

        restarted = EmbeddedRedis(port=persistent_redis.port, data_dir=persistent_redis.data_dir,
                                  appendonly=True).start()
        persistent_redis.proc = restarted.proc
        assert api.get(f"/api/jobs/{job_id}").json()["status"] == "queued"
        assert api.get("/readyz").json()["reasons"] == [
            "no live workers: no worker process has sent a heartbeat within its timeout"]


def test_ready_needs_a_live_worker(outage_settings):
    """``/readyz``: 503 "no live workers" until a worker process beats, ready while its heartbeat
    lives, and not ready again once it has expired (the process died)."""
    store = JobStore.from_url(outage_settings.redis_url, outage_settings.key_prefix)
    with TestClient(create_app(outage_settings)) as api:
        r = api.get("/readyz")
        assert r.status_code == 503
        assert r.json()["reasons"] == [
            "no live workers: no worker process has sent a heartbeat within its timeout"]
        store.heartbeat("host:1", {"state": "idle"}, ttl=0.5)
        r = api.get("/readyz")
        assert (r.status_code, r.json()) == (200, {"status": "ok"})
        time.sleep(0.6)  # the heartbeat expires: the worker is lost
        assert api.get("/readyz").status_code == 503
    store.close()


def test_client_waits_through_an_outage_with_backoff_and_says_why(persistent_redis,
                                                                  outage_settings, tiny_scene):
    """``Client.job`` (what ``lucent submit --wait`` polls) while Redis is down: it retries with
    growing delays, telling each 503's reason, and returns the job once Redis is back; a server
    down for longer than the client's patience ends in ``Unavailable`` with the last reason."""
    said: list[str] = []
    with TestClient(create_app(outage_settings)) as api:
        client = Client("http://testserver", say=said.append, patience=60.0)
        client.http = api
        job_id = client.submit(tiny_scene)["id"]
        _kill(persistent_redis)

        # The restarted server gets PR_SET_PDEATHSIG from the thread that starts it (Linux ties it
        # to the thread, not the process): that thread must live until the server is killed, or
        # the server is sent SIGTERM as soon as the thread returns (as `lucent up`'s long-lived
        # supervisor thread does)
        done = threading.Event()
        back = threading.Event()  # the restarted server is persistent_redis.proc (kill that one)

        def restart_later() -> None:
            time.sleep(2.0)
            restarted = EmbeddedRedis(port=persistent_redis.port,
                                      data_dir=persistent_redis.data_dir, appendonly=True).start()
            persistent_redis.proc = restarted.proc
            back.set()
            done.wait(120.0)

        restarter = threading.Thread(target=restart_later)
        restarter.start()
        try:
            job = client.job(job_id)
        except BaseException:
            done.set()
            restarter.join()
            raise
        assert job["id"] == job_id and job["status"] == "queued"
        assert len(said) >= 2
        assert all("Redis refused the connection" in line and "retrying in" in line
                   for line in said), said
        # The client's backoff, each delay at least the server's Retry-After (1 s).
        delays = [float(line.split("retrying in ")[1].split(" s")[0]) for line in said]
        assert delays == [max(d, 1.0) for d in RETRY_DELAYS[:len(delays)]], delays

        # The client may see the server answer before the thread has recorded its process
        assert back.wait(30.0)
        _kill(persistent_redis)
        done.set()
        restarter.join()
        impatient = Client("http://testserver", say=said.append, patience=1.0)
        impatient.http = api
        with pytest.raises(Unavailable, match="Redis refused the connection"):
            impatient.job(job_id)
