"""What a small scene's `POST /api/jobs` costs, first in a service process and after.

    .venv/bin/python -m bench.first_submission [--scene examples/cornell_box.json] [--posts 4]
        [--kernel packet|scalar]

The API in this process (FastAPI's test client) on an embedded Redis, with ``worker_kernel``
``--kernel`` (the farm plans for it; on a packet farm the submission asks whether the packet
kernel covers the scene, ``services.farm.jobs.packet_covers``, which compiles a small scene);
no worker. Each submission is timed from the request to the answer, then cancelled. The first
includes what a service process loads once (the scene compiler's numba functions, from the
cache).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.settings import Settings
from services.launcher import EmbeddedRedis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="examples/cornell_box.json")
    parser.add_argument("--posts", type=int, default=4)
    parser.add_argument("--kernel", choices=["packet", "scalar"], default="packet")
    args = parser.parse_args()
    scene = json.loads(Path(args.scene).read_text())
    server = EmbeddedRedis().start()
    try:
        settings = Settings(redis_url=server.url, key_prefix="first", worker_kernel=args.kernel)
        with TestClient(create_app(settings)) as client:
            for i in range(args.posts):
                t0 = time.perf_counter()
                r = client.post("/api/jobs", json={"scene": scene})
                ms = 1e3 * (time.perf_counter() - t0)
                job = r.json()
                print(f"submission {i}: {r.status_code} in {ms:.0f} ms, first pass "
                      f"{job.get('spp_per_pass')} spp, {job.get('passes')} passes a tile",
                      flush=True)
                client.delete(f"/api/jobs/{job['id']}")
    finally:
        server.stop()


if __name__ == "__main__":
    main()
