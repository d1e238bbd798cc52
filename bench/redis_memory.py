"""Redis memory after 100 finished 320×240 jobs against none (issue #20).

    .venv/bin/python -m bench.redis_memory [--jobs 100] [--workers 2] [--spp 4]

``lucent up``'s farm on this machine (an embedded Redis, ``--workers`` worker processes, the API
with its sweeper, a temporary data folder): Redis's ``used_memory`` and its keys once the workers
are warm and idle with no job ever submitted, then after ``--jobs`` Cornell boxes of 320×240 at
``--spp`` samples (64-pixel tiles, one pass each) have finished and been archived (their records
in SQLite, their images in the blob store). Prints both, the keys that differ, and how long the
jobs took.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import httpx
import redis

from services.launcher import LocalFarm, free_port

ROOT = Path(__file__).resolve().parents[1]


def used(client: redis.Redis) -> tuple[int, int, set[str]]:
    """used_memory, the part of it that is the data (keys and values: used_memory_dataset), the
    keys."""
    info = client.info("memory")
    return (int(info["used_memory"]), int(info["used_memory_dataset"]),
            {k.decode() for k in client.keys("*")})


def wait(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--spp", type=int, default=4)
    args = ap.parse_args()
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 320, "height": 240}
    scene["render"]["spp"] = args.spp
    with tempfile.TemporaryDirectory(prefix="lucent-bench-") as data:
        os.environ["LUCENT_DATA_DIR"] = data
        os.environ.pop("DATABASE_URL", None)
        os.environ["LUCENT_KEY_PREFIX"] = "lucent"
        with LocalFarm(port=free_port(), workers=args.workers, quiet=True) as farm:
            assert farm.redis_url is not None
            client = redis.Redis.from_url(farm.redis_url)
            api = httpx.Client(base_url=farm.url, timeout=60)
            wait(lambda: sum(w["state"] == "idle" for w in api.get("/api/workers").json()["data"])
                 >= args.workers, 600, "warm workers")
            time.sleep(2.0)  # a heartbeat of each
            before, data_before, keys_before = used(client)
            t0 = time.perf_counter()
            for i in range(args.jobs):
                r = api.post("/api/jobs", json={"scene": scene, "name": f"bench {i}",
                                                "tile_size": 64, "spp_per_pass": args.spp})
                r.raise_for_status()
            wait(lambda: api.get("/api/jobs?status=done&limit=1").json()["count"] == args.jobs,
                 1800, "the jobs done")
            wait(lambda: client.zcard("lucent:jobs") == 0, 120, "the jobs archived")
            seconds = time.perf_counter() - t0
            time.sleep(5.0)  # Redis's cron shrinks the emptied hash tables
            after, data_after, keys_after = used(client)
            print(f"{args.jobs} jobs of 320x240 at {args.spp} spp, {args.workers} worker "
                  f"processes: done and archived in {seconds:.1f} s")
            print(f"Redis used_memory: {before} bytes with none, {after} bytes after them "
                  f"({after - before:+d}), of which data {data_before} -> {data_after} "
                  f"({data_after - data_before:+d}); "
                  f"keys {len(keys_before)} -> {len(keys_after)}")
            print(f"keys added: {sorted(keys_after - keys_before)}; "
                  f"removed: {sorted(keys_before - keys_after)}")
            blobs = sum(f.stat().st_size for f in Path(data, "blobs").rglob("*") if f.is_file())
            print(f"blob store: {blobs} bytes; job database: "
                  f"{Path(data, 'lucent.db').stat().st_size} bytes")
            api.close()
            client.close()


if __name__ == "__main__":
    main()
