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
import os
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.records import Records
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import start_worker, terminate
from tests.conftest import embedded_or_given_redis, wait_until

ROOT = Path(__file__).resolve().parents[2]

# Settings made by a test itself keep done jobs' images here, not in the user's data folder.
os.environ.setdefault("LUCENT_DATA_DIR", tempfile.mkdtemp(prefix="lucent-test-data-"))
# With DATABASE_URL (PostgreSQL), their job records go to a schema of this session's, dropped at
# its end; without, to SQLite in their data folder.
if os.environ.get("DATABASE_URL"):
    os.environ.setdefault("LUCENT_DATABASE_SCHEMA", f"lucent_session_{uuid.uuid4().hex[:10]}")

# Generous: a cold numba cache compiles the kernels in each worker process (~15 s each on 2 cores).
WORKER_START_TIMEOUT = 240.0
JOB_TIMEOUT = 180.0


@pytest.fixture(scope="session")
def redis_base_url() -> Iterator[str]:
    yield from embedded_or_given_redis()


def _prefix() -> str:
    return f"lucent-test-{uuid.uuid4().hex[:10]}"


def farm_state(prefix: str, folder: Path) -> dict:
    """Settings that give a test farm job records and a blob store of its own: ``folder`` as its
    data folder (SQLite there) and, when ``DATABASE_URL`` names a PostgreSQL database, a schema
    named after its Redis key prefix (``drop_farm_state`` removes it)."""
    state: dict = {"data_dir": folder}
    if os.environ.get("DATABASE_URL"):
        state["database_schema"] = prefix.replace("-", "_").lower()
    return state


def drop_farm_state(settings: Settings) -> None:
    if settings.database_schema and settings.database_url:
        from sqlalchemy import text

        from services.farm.records import engine_for

        engine = engine_for(settings.database_url)
        with engine.begin() as conn:
            conn.execute(text(f'DROP SCHEMA IF EXISTS "{settings.database_schema}" CASCADE'))
        engine.dispose()


@pytest.fixture(scope="session", autouse=True)
def _drop_session_schema() -> Iterator[None]:
    yield
    if os.environ.get("DATABASE_URL"):
        drop_farm_state(Settings())


@pytest.fixture
def settings(redis_base_url: str, tmp_path: Path) -> Iterator[Settings]:
    """A fresh Redis key prefix, data folder and (on PostgreSQL) schema: no test sees another's
    jobs."""
    prefix = _prefix()
    s = Settings(redis_url=redis_base_url, key_prefix=prefix,
                 **farm_state(prefix, tmp_path / "data"))
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


def records_of(settings: Settings) -> Records:
    """The job records of a farm with these settings (its data folder, or its schema)."""
    records = Records(settings.database, settings.database_schema)
    records.migrate()
    return records


@pytest.fixture(scope="session")
def farm(redis_base_url: str, tmp_path_factory) -> Iterator[Farm]:
    prefix = _prefix()
    log_path = tmp_path_factory.mktemp("farm") / "worker.log"
    settings = Settings(redis_url=redis_base_url, key_prefix=prefix, heartbeat_interval=0.5,
                        **farm_state(prefix, log_path.parent / "data"))
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
    """The API of the farm; done jobs keep their accumulations in Redis (``archive_done`` off):
    the tests read every pixel's sample count from them (test_farm_retention archives)."""
    with TestClient(create_app(farm.settings.model_copy(update={"archive_done": False}))) as c:
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
