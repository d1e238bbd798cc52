"""A brief version of ``bench/load.py``: 20 submissions and 40 pollers for a few seconds against
the API served by uvicorn on 127.0.0.1 and the session's workers; no 5xx, every job done."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import pytest

from bench.load import run_load, small_scene
from services.farm.settings import get_settings
from services.launcher import LocalFarm, free_port


@pytest.fixture
def served_farm(farm, monkeypatch) -> Iterator[LocalFarm]:
    """The API under uvicorn (in a thread) on the session farm's Redis and key prefix."""
    # LocalFarm reads the environment (get_settings) and sets REDIS_URL: monkeypatch restores it.
    monkeypatch.setenv("REDIS_URL", farm.settings.redis_url)
    monkeypatch.setenv("LUCENT_KEY_PREFIX", farm.settings.key_prefix)
    monkeypatch.setenv("LUCENT_API_TOKEN", "")
    server = LocalFarm(port=free_port(), workers=0, redis_url=farm.settings.redis_url,
                       quiet=True).start()
    try:
        yield server
    finally:
        server.stop()
        get_settings.cache_clear()


@pytest.mark.slow
def test_concurrent_submissions_and_pollers_get_no_5xx_and_every_job_completes(served_farm):
    submissions = 20
    load = run_load(served_farm.url, submissions=submissions, pollers=40, seconds=4.0,
                    interval=0.2, scene=small_scene(), job_timeout=120.0)
    # In a thread of its own: the dashboard tests' session-wide playwright (sync API) keeps an
    # event loop running in the main thread, where asyncio.run() refuses to start another.
    with ThreadPoolExecutor(max_workers=1) as pool:
        result = pool.submit(asyncio.run, load).result()
    assert result.server_errors == 0, result.report()
    assert result.errors == [], result.errors[:5]
    assert len(result.job_ids) == submissions
    assert result.final == {job_id: "done" for job_id in result.job_ids}, result.report()
    # Every endpoint was exercised, many times.
    for endpoint in ("POST /api/jobs", "GET /api/jobs/{id}", "GET /api/jobs", "GET /api/workers"):
        assert len(result.latencies[endpoint]) >= (submissions if "POST" in endpoint else 20)
    assert result.ok(submissions)
