"""Dashboard fixtures: a real farm (Redis, Celery worker processes, the API under uvicorn in its own
process on a free port) and headless Chromium driven by Playwright.

- ``redis_base_url``: ``REDIS_URL`` when set, else an embedded redis-server of its own
  (tests/conftest.py, ``embedded_or_given_redis``).
- ``dashboard``: for one test module, a worker node (``--concurrency 2``) and ``uvicorn
  services.api.main:app`` on a fresh key prefix, heartbeats every 0.5 s.
- ``browser``: Debian's ``/usr/bin/chromium`` (``make setup`` installs it where it can); tests skip
  with the reason when it is missing. ``page`` is a fresh page at a laptop-sized viewport.
- ``artifacts``: a folder for the screenshots a test saves (under pytest's tmp path; its path is
  printed in the report's header line of each test that saves one).
"""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import redis

from services.farm.store import JobStore
from services.launcher import free_port, start_worker, terminate
from tests.conftest import embedded_or_given_redis, wait_until

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
# A cold numba cache compiles the kernels in each worker process (~15 s each on 2 cores).
WORKER_START_TIMEOUT = 240.0
HEARTBEAT = 0.5


@pytest.fixture(scope="session")
def redis_base_url() -> Iterator[str]:
    yield from embedded_or_given_redis()


@dataclass
class Dashboard:
    url: str
    prefix: str
    redis_url: str
    server: subprocess.Popen
    worker: subprocess.Popen
    log: Path

    def store(self) -> JobStore:
        return JobStore(redis.Redis.from_url(self.redis_url), self.prefix)

    def api(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=30)


def start_api(redis_url: str, prefix: str, port: int, log) -> subprocess.Popen:
    """``uvicorn services.api.main:app``, its own process (the app reads its settings from env),
    with a data folder of its own beside the log (its job records: no other run's jobs listed)."""
    env = {**os.environ, "REDIS_URL": redis_url, "LUCENT_KEY_PREFIX": prefix,
           "LUCENT_HEARTBEAT_INTERVAL": str(HEARTBEAT), "LUCENT_API_TOKEN": "",
           "PYTHONUNBUFFERED": "1", "LUCENT_DATA_DIR": str(Path(log.name).parent / "data")}
    if os.environ.get("DATABASE_URL"):  # a schema of its own (tests/conftest.py, farm_state)
        env["LUCENT_DATABASE_SCHEMA"] = prefix.replace("-", "_")
    return subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "services.api.main:app", "--host", "127.0.0.1",
         "--port", str(port), "--log-level", "warning"],
        cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)


@pytest.fixture(scope="module")
def dashboard(redis_base_url: str, tmp_path_factory) -> Iterator[Dashboard]:
    prefix = f"lucent-dash-{uuid.uuid4().hex[:10]}"
    log_path = tmp_path_factory.mktemp("dashboard") / "farm.log"
    port = free_port()
    with open(log_path, "w") as log:
        worker = start_worker(
            redis_base_url, concurrency=2, threads=1, name=f"{prefix}@%h", log=log,
            extra_env={"LUCENT_KEY_PREFIX": prefix, "LUCENT_HEARTBEAT_INTERVAL": str(HEARTBEAT),
                       "LUCENT_API_TOKEN": ""})
        server = start_api(redis_base_url, prefix, port, log)
        d = Dashboard(f"http://127.0.0.1:{port}", prefix, redis_base_url, server, worker, log_path)
        store = d.store()

        def ready() -> bool:
            if worker.poll() is not None or server.poll() is not None:
                return True
            try:
                httpx.get(f"{d.url}/readyz", timeout=1).raise_for_status()
            except httpx.HTTPError:
                return False
            return sum(w.get("state") == "idle" for w in store.workers()) >= 2

        try:
            wait_until(ready, WORKER_START_TIMEOUT, "the API and two warm workers", interval=0.2)
            assert worker.poll() is None and server.poll() is None, log_path.read_text()[-3000:]
            yield d
        finally:
            terminate(server, 10.0)
            terminate(worker, 30.0)
            store.r.close()


@pytest.fixture(scope="session")
def browser():
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} is missing: `apt-get install -y chromium` (make setup does it "
                    "as root where apt-get exists)")
    from playwright.sync_api import sync_playwright  # the `test` extra

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1366, "height": 900})
    pg = context.new_page()
    console: list[str] = []
    # Failed requests are logged below with their URL (a 422 is an answer the page shows).
    pg.on("console", lambda m: console.append(f"{m.type}: {m.text}")
          if m.type == "error" and not m.text.startswith("Failed to load resource") else None)
    pg.on("pageerror", lambda e: console.append(f"pageerror: {e}"))
    pg.on("response", lambda r: console.append(f"HTTP {r.status} {r.url}")
          if r.status >= 400 and r.status != 422 else None)
    pg.set_default_timeout(30_000)
    pg.console_errors = console  # type: ignore[attr-defined]
    yield pg
    context.close()


@pytest.fixture(scope="session")
def artifacts(tmp_path_factory) -> Path:
    """Screenshots of the pages the tests visit (kept with pytest's temporary folders)."""
    return tmp_path_factory.mktemp("dashboard-screenshots")
