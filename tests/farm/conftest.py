"""Farm fixtures: a real Redis, real Celery worker processes, the API in-process.

- ``redis_base_url``: ``REDIS_URL`` when set, else an embedded redis-server of its own for the
  session (tests/conftest.py, ``embedded_or_given_redis``; ``wait_until`` is there too).
- ``settings``: a fresh key prefix per test, so that tests never see each other's jobs.
- ``farm``: one worker node (``--concurrency 2``, single-threaded processes) started with
  ``subprocess`` for the session, on its own key prefix; ``farm_client`` is the API (FastAPI's
  TestClient, lifespan and sweeper included) on the same prefix.

Celery's eager mode is never used: every task crosses Redis to a worker process.
"""

from __future__ import annotations

import copy
import json
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.records import JobRecord, Records
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import start_worker, terminate
from tests.conftest import drop_farm_state, embedded_or_given_redis, farm_state, wait_until

ROOT = Path(__file__).resolve().parents[2]

# Generous: a cold numba cache compiles the kernels in each worker process (~15 s each on 2 cores).
WORKER_START_TIMEOUT = 240.0
JOB_TIMEOUT = 180.0


@pytest.fixture(scope="session")
def redis_base_url() -> Iterator[str]:
    yield from embedded_or_given_redis()


def _prefix() -> str:
    return f"lucent-test-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def settings(redis_base_url: str, tmp_path) -> Iterator[Settings]:
    """A fresh Redis key prefix, data folder and (on PostgreSQL) schema: no test sees another's
    jobs."""
    prefix = _prefix()
    s = Settings(redis_url=redis_base_url, key_prefix=prefix, **farm_state(prefix, tmp_path))
    yield s
    drop_farm_state(s)


@pytest.fixture
def store(settings: Settings) -> Iterator[JobStore]:
    s = JobStore(redis.Redis.from_url(settings.redis_url), settings.key_prefix)
    yield s
    s.r.close()


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    """The API on a fresh prefix (the session's workers skip its tasks: no such job there)."""
    with TestClient(create_app(settings)) as c:
        yield c


@dataclass
class Farm:
    proc: object
    settings: Settings
    log: Path

    def store(self) -> JobStore:
        return JobStore(redis.Redis.from_url(self.settings.redis_url), self.settings.key_prefix)

    def records(self) -> Records:
        return records_of(self.settings)


@pytest.fixture(scope="session")
def farm(redis_base_url: str, tmp_path_factory) -> Iterator[Farm]:
    prefix = _prefix()
    log_path = tmp_path_factory.mktemp("farm") / "worker.log"
    settings = Settings(redis_url=redis_base_url, key_prefix=prefix, heartbeat_interval=0.5,
                        **farm_state(prefix, log_path.parent))
    with open(log_path, "w") as log:
        proc = start_worker(
            redis_base_url, concurrency=2, threads=1, name=f"{prefix}@%h", log=log,
            extra_env={"LUCENT_KEY_PREFIX": prefix, "LUCENT_HEARTBEAT_INTERVAL": "0.5",
                       "LUCENT_API_TOKEN": ""},
        )
        f = Farm(proc, settings, log_path)
        store = f.store()
        try:
            wait_until(
                lambda: sum(w.get("state") == "idle" for w in store.workers()) >= 2
                or proc.poll() is not None,
                WORKER_START_TIMEOUT, "two warm worker processes", interval=0.2)
            assert proc.poll() is None, f"the worker exited: {log_path.read_text()[-3000:]}"
            yield f
        finally:
            terminate(proc, 30.0)
            store.r.close()
            drop_farm_state(settings)


@pytest.fixture
def farm_client(farm: Farm) -> Iterator[TestClient]:
    with TestClient(create_app(farm.settings)) as c:
        yield c


@pytest.fixture(scope="session")
def cornell() -> dict:
    return json.loads((ROOT / "examples" / "cornell_box.json").read_text())


@pytest.fixture
def tiny_scene(cornell: dict) -> dict:
    """The Cornell box at 32x24, 16 spp: a job of a few hundred milliseconds."""
    scene = copy.deepcopy(cornell)
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 16
    return scene


def wait_for_job(client: TestClient, job_id: str, statuses=("done", "failed", "cancelled"),
                 timeout: float = JOB_TIMEOUT) -> dict:
    def poll():
        body = client.get(f"/api/jobs/{job_id}").json()
        return body if body["status"] in statuses else None

    return wait_until(poll, timeout, f"job {job_id} to reach {statuses}")  # type: ignore[return-value]


@pytest.fixture(name="wait_for_job")
def _wait_for_job_fixture():
    return wait_for_job


# --- a finished job leaves Redis (services/farm/archive.py) --------------------------------------


def records_of(settings: Settings) -> Records:
    """The job records of a farm with these settings (its data folder or schema)."""
    return Records(settings.database, settings.database_schema)


def job_status(store: JobStore, records: Records, job_id: str) -> str | None:
    """The job's status: Redis's while Redis holds the job, else its record's."""
    status = store.get_status(job_id)
    if status is None:
        record = records.get(job_id)
        status = record.meta.status if record is not None else None
    return status


def job_keys(store: JobStore, job_id: str) -> list[str]:
    """Every Redis key of the job, and its entries in the job list and the pending set."""
    found = [k.decode() for k in store.r.scan_iter(match=f"{store.k('job', job_id)}*")]
    if store.r.zscore(store.k("jobs"), job_id) is not None:
        found.append(f"{store.k('jobs')} member")
    found += [p for p in store.pending_passes() if job_id in p]
    return found


def archived(records: Records, job_id: str, timeout: float = JOB_TIMEOUT) -> JobRecord:
    """Wait until the sweeper has archived the job; its record."""
    def done() -> JobRecord | None:
        record = records.get(job_id)
        return record if record is not None and record.archived_at is not None else None

    return wait_until(done, timeout, f"job {job_id} archived")  # type: ignore[return-value]


def assert_archived_whole(records: Records, store: JobStore, job_id: str, spp: int) -> JobRecord:
    """Archived done with every pass merged once and every pixel at exactly ``spp`` samples
    (kept or dropped: counted from the frame when it was archived), every tile done, and nothing
    of it left in Redis."""
    record = archived(records, job_id)
    meta = record.meta
    assert meta.status == "done", meta
    assert meta.tasks_merged == meta.plan.n_tasks
    assert record.pixel_samples == (spp, spp), record.pixel_samples
    assert set((record.tiles or {})["state"].values()) == {"done"}
    assert not job_keys(store, job_id)
    return record
