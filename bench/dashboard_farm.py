"""A farm for the dashboard's scripts (bench/dashboard_screenshots.py, bench/dashboard_load.py):
an embedded Redis, one worker node and ``uvicorn services.api.main:app`` in its own process (so that
its CPU time can be measured alone), on free localhost ports, with a data folder of its own (its
job records and images: not the user's farm's, whose jobs it would list, and mark failed as lost
where its Redis does not hold them); everything stopped and removed on exit."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import redis

from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, free_port, start_worker, terminate

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]


class DashboardFarm:
    def __init__(self, workers: int = 2, heartbeat: float = 0.5, api_workers: int = 1):
        self.workers = workers
        self.api_workers = api_workers
        self.heartbeat = heartbeat
        self.prefix = f"lucent-bench-{uuid.uuid4().hex[:8]}"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.redis: EmbeddedRedis | None = None
        self.worker: subprocess.Popen | None = None
        self.server: subprocess.Popen | None = None
        self.data: Path | None = None

    def __enter__(self) -> DashboardFarm:
        self.redis = EmbeddedRedis().start()
        self.data = Path(tempfile.mkdtemp(prefix="lucent-bench-data-"))
        env = {"LUCENT_KEY_PREFIX": self.prefix, "LUCENT_HEARTBEAT_INTERVAL": str(self.heartbeat),
               "LUCENT_API_TOKEN": "", "LUCENT_DATA_DIR": str(self.data)}
        if self.workers:
            self.worker = start_worker(self.redis.url, self.workers, 1, extra_env=env,
                                       log=subprocess.DEVNULL)
        self.server = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "services.api.main:app", "--host", "127.0.0.1",
             "--port", str(self.port), "--log-level", "warning", "--no-access-log",
             "--workers", str(self.api_workers)],
            cwd=ROOT, env={**os.environ, **env, "REDIS_URL": self.redis.url})
        store = self.store()
        deadline = time.monotonic() + 240
        while True:
            try:
                # /healthz: /readyz would wait for a worker, and this farm may have none
                httpx.get(f"{self.url}/healthz", timeout=1).raise_for_status()
                idle = sum(w.get("state") == "idle" for w in store.workers())
                if idle >= self.workers:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline or self.server.poll() is not None:
                self.__exit__()
                raise RuntimeError("the farm did not start")
            time.sleep(0.2)
        store.r.close()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.server is not None:
            terminate(self.server, 10.0)
        if self.worker is not None:
            terminate(self.worker, 30.0)
        if self.redis is not None:
            self.redis.stop()
        if self.data is not None:
            shutil.rmtree(self.data, ignore_errors=True)

    def store(self) -> JobStore:
        assert self.redis is not None
        return JobStore(redis.Redis.from_url(self.redis.url), self.prefix)

    def submit(self, client: httpx.Client, example: str, **changes) -> dict:
        import json

        scene = json.loads((ROOT / "examples" / f"{example}.json").read_text())
        film = changes.pop("film", None)
        if film:
            scene["film"] = film
        spp = changes.pop("spp", None)
        if spp:
            scene["render"]["spp"] = spp
        target = changes.pop("target_error", None)
        if target:
            scene["render"]["target_error"] = target
        r = client.post("/api/jobs", json={"scene": scene, "name": example, **changes})
        r.raise_for_status()
        return r.json()

    def wait(self, client: httpx.Client, job_id: str, statuses=("done", "failed", "cancelled"),
             timeout: float = 300.0) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            job = client.get(f"/api/jobs/{job_id}").json()
            if job["status"] in statuses or time.monotonic() > deadline:
                return job
            time.sleep(0.2)
