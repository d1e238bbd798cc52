"""``GET /api/jobs?limit=50`` latency with 100, 10 000 and 100 000 jobs stored (issue #20).

    .venv/bin/python -m bench.jobs_listing [--counts 100 10000 100000] [--requests 400]
        [--database sqlite postgresql]

For each database (SQLite in a temporary data folder; PostgreSQL at ``DATABASE_URL``, by default
``postgresql://postgres@127.0.0.1:5432/test``, in a schema of its own dropped at the end)
the job table is filled with finished jobs (a quarter failed) up to each count, and the API,
``uvicorn services.api.main:app`` in a process of its own on an embedded Redis as ``lucent up``
runs it (no workers: none is needed to list), is asked ``--requests`` times in a row, over one
kept-alive connection, for the first page of 50 (what the dashboard's jobs page polls) and for the
first page of the failed ones.
Prints p50 and p99 in milliseconds.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
from sqlalchemy import insert, text

from services.farm.records import Records, jobs
from services.launcher import EmbeddedRedis, free_port, terminate

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PG = "postgresql://postgres@127.0.0.1:5432/test"


def fill(records: Records, have: int, want: int) -> None:
    """Add finished jobs to reach ``want`` rows (created a second apart, newest last)."""
    t0 = time.time() - want
    rows = []
    for i in range(have, want):
        rows.append({
            "id": uuid.uuid4().hex, "name": f"shot {i}", "priority": 0,
            "width": 320, "height": 240, "spp": 64, "tile_size": 32, "spp_per_pass": 8,
            "max_spp_per_pass": 64, "tasks_total": 400, "tasks_merged": 400,
            "samples_merged": 320 * 240 * 64, "dropped": 0, "version": 400,
            "status": "failed" if i % 4 == 0 else "done", "created_at": t0 + i,
            "started_at": t0 + i + 1, "finished_at": t0 + i + 30, "error": None,
            "methods": json.dumps({}), "archived_at": t0 + i + 31,
            "image_exr": "sha256:" + f"{i:064x}", "image_png": "sha256:" + f"{i + 1:064x}",
        })
    with records.engine.begin() as conn:
        for start in range(0, len(rows), 5000):
            conn.execute(insert(jobs), rows[start:start + 5000])
        if records.engine.dialect.name == "postgresql":
            conn.execute(text("ANALYZE jobs"))


def latencies(url: str, path: str, n: int) -> np.ndarray:
    out = np.empty(n)
    with httpx.Client(base_url=url, timeout=30) as c:
        for _ in range(20):
            c.get(path).raise_for_status()  # warm: connections, caches
        for k in range(n):
            t0 = time.perf_counter()
            c.get(path).raise_for_status()
            out[k] = time.perf_counter() - t0
    return out * 1e3


def run(database: str, counts: list[int], n: int) -> None:
    redis_server = EmbeddedRedis().start()
    data = tempfile.TemporaryDirectory(prefix="lucent-bench-")
    schema = f"bench_{uuid.uuid4().hex[:8]}"
    env = {**os.environ, "REDIS_URL": redis_server.url, "LUCENT_DATA_DIR": data.name,
           "LUCENT_KEY_PREFIX": f"bench-{uuid.uuid4().hex[:8]}", "LUCENT_API_TOKEN": ""}
    if database == "postgresql":
        env["DATABASE_URL"] = url = os.environ.get("DATABASE_URL") or DEFAULT_PG
        env["LUCENT_DATABASE_SCHEMA"] = schema
        records = Records(url, schema)
    else:
        env.pop("DATABASE_URL", None)
        records = Records(f"sqlite:///{data.name}/lucent.db")
    records.migrate()
    port = free_port()
    api = subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "services.api.main:app", "--port", str(port),
         "--log-level", "warning"], cwd=ROOT, env=env)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                httpx.get(f"{base}/api/jobs", timeout=1).raise_for_status()
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline or api.poll() is not None:
                    raise RuntimeError("the API did not start") from None
                time.sleep(0.1)
        have = 0
        for count in counts:
            fill(records, have, count)
            have = count
            for label, path in [("limit=50", "/api/jobs?limit=50"),
                                ("status=failed&limit=50", "/api/jobs?status=failed&limit=50")]:
                ms = latencies(base, path, n)
                print(f"{database:10s} {count:>7d} jobs  GET /api/jobs?{label:24s} "
                      f"p50 {np.percentile(ms, 50):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms",
                      flush=True)
    finally:
        terminate(api, 10.0)
        if database == "postgresql":
            with records.engine.begin() as conn:
                conn.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
        records.close()
        redis_server.stop()
        data.cleanup()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--counts", type=int, nargs="+", default=[100, 10_000, 100_000])
    ap.add_argument("--requests", type=int, default=400)
    ap.add_argument("--database", nargs="+", default=["sqlite", "postgresql"],
                    choices=["sqlite", "postgresql"])
    args = ap.parse_args()
    for database in args.database:
        run(database, sorted(args.counts), args.requests)


if __name__ == "__main__":
    main()
