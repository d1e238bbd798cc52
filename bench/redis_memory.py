"""Redis memory after N finished jobs, with done jobs archived (their image to the blob store,
their tile keys out of Redis) and without (``--no-archive``: as before the blob store).

    .venv/bin/python -m bench.redis_memory [--jobs 20] [--size 64x48] [--spp 16] [--no-archive]

An embedded Redis, one worker node (``--concurrency 2``) and the API in-process (its sweeper
archives); the Cornell box at ``--size`` is submitted ``--jobs`` times with distinct seeds, all
waited for, then the sweeper is given a few intervals and ``INFO memory`` ``used_memory`` is read:
before the first job and after the last.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import uuid
from pathlib import Path

import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.settings import Settings
from services.launcher import EmbeddedRedis, start_worker, terminate

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=20)
    ap.add_argument("--size", default="64x48")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--no-archive", action="store_true")
    args = ap.parse_args()
    width, height = map(int, args.size.split("x"))
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": width, "height": height}
    scene["render"]["spp"] = args.spp

    server = EmbeddedRedis().start()
    prefix = f"lucent-bench-{uuid.uuid4().hex[:8]}"
    r = redis.Redis.from_url(server.url)
    with tempfile.TemporaryDirectory() as data:
        settings = Settings(redis_url=server.url, key_prefix=prefix, data_dir=Path(data),
                            archive_done=not args.no_archive)
        worker = start_worker(server.url, concurrency=2, extra_env={
            "LUCENT_KEY_PREFIX": prefix, "LUCENT_API_TOKEN": ""})
        try:
            with TestClient(create_app(settings)) as client:
                info = r.info("memory")
                before, before_data = info["used_memory"], info["used_memory_dataset"]
                keys_before = sorted(k.decode() for k in r.keys("*"))
                ids = [client.post("/api/jobs", json={"scene": {
                    **scene, "render": {**scene["render"], "seed": i + 1}}}).json()["id"]
                    for i in range(args.jobs)]
                deadline = time.monotonic() + 600
                while any(client.get(f"/api/jobs/{j}").json()["status"] not in
                          ("done", "failed", "cancelled") for j in ids):
                    assert time.monotonic() < deadline, "jobs did not finish"
                    time.sleep(0.5)
                time.sleep(5 * settings.sweep_interval)  # the sweeper archives
                info = r.info("memory")
                after, after_data = info["used_memory"], info["used_memory_dataset"]
                keys_after = sorted(k.decode() for k in r.keys("*"))
                keys = len(keys_after)
        finally:
            terminate(worker, 30.0)
            server.stop()
    print(f"{args.jobs} jobs of {width}x{height} at {args.spp} spp, archive "
          f"{'off' if args.no_archive else 'on'}: used_memory {before} -> {after} bytes "
          f"(+{after - before}, {(after - before) / args.jobs:.0f} a job), {keys} keys; "
          f"used_memory_dataset {before_data} -> {after_data} (+{after_data - before_data})")
    print(f"keys before the first job: {keys_before}")
    print(f"keys after the last: {keys_after}")


if __name__ == "__main__":
    main()
