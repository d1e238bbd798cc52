"""/healthz latency while a large scene is submitted (issue #24: the event loop stalled).

    .venv/bin/python -m bench.submit_latency [--grid 667] [--repeats 2]

The API runs under uvicorn on an embedded Redis, as ``lucent up`` runs it; a scene with an inline
grid mesh of 2 x grid² triangles (``--grid 667``: 889 778 triangles, a 47 MB body) is posted
``--repeats`` times while another client asks ``/healthz`` every 10 ms. For each submission:
its time and status, and /healthz's answers during it (count, median and largest latency). The
first submission of a service also starts its intake process (``services/api/intake.py``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
import uuid
from pathlib import Path

import httpx
import uvicorn

from renderer.geometry.meshgen import sheet
from services.api.main import create_app
from services.farm.settings import Settings
from services.launcher import EmbeddedRedis, free_port

ROOT = Path(__file__).resolve().parents[1]


def scene_body(grid: int) -> bytes:
    """The Cornell box at 32x24, 1 spp, plus a grid x grid sheet of quads as an inline mesh."""
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 1
    vertices, triangles = sheet(grid, z=0.123456789)
    scene["objects"].append({"type": "mesh", "vertices": vertices.tolist(),
                             "triangles": triangles.tolist(), "material": "white"})
    return json.dumps({"scene": scene}).encode()


def measure(url: str, body: bytes) -> tuple[int, float, list[float]]:
    """(status, seconds) of one submission, and /healthz's latencies meanwhile."""
    answer: dict = {}

    def submit() -> None:
        with httpx.Client(base_url=url, timeout=600) as c:
            t0 = time.perf_counter()
            r = c.post("/api/jobs", content=body, headers={"content-type": "application/json"})
            answer.update(status=r.status_code, seconds=time.perf_counter() - t0)

    latencies = []
    with httpx.Client(base_url=url, timeout=600) as probe:
        submission = threading.Thread(target=submit)
        submission.start()
        while submission.is_alive():
            t0 = time.perf_counter()
            probe.get("/healthz")
            latencies.append(time.perf_counter() - t0)
            time.sleep(0.01)
        submission.join()
    return answer["status"], answer["seconds"], latencies


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", type=int, default=667, help="the mesh's quads a side (default 667)")
    ap.add_argument("--repeats", type=int, default=2, help="submissions (default 2)")
    args = ap.parse_args()
    body = scene_body(args.grid)
    print(f"body {len(body) / 1e6:.1f} MB ({2 * args.grid**2} triangles)")
    redis_server = EmbeddedRedis().start()
    settings = Settings(redis_url=redis_server.url, key_prefix=f"bench-{uuid.uuid4().hex[:8]}")
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        while not server.started:
            time.sleep(0.05)
        url = f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=url) as c:
            idle = []
            for _ in range(20):
                t0 = time.perf_counter()
                c.get("/healthz")
                idle.append(time.perf_counter() - t0)
        print(f"/healthz idle: median {statistics.median(idle) * 1e3:.1f} ms")
        for k in range(args.repeats):
            status, seconds, latencies = measure(url, body)
            print(f"submission {k + 1}: {status} in {seconds:.2f} s; /healthz meanwhile: "
                  f"{len(latencies)} answers, median {statistics.median(latencies) * 1e3:.1f} ms, "
                  f"largest {max(latencies) * 1e3:.0f} ms")
    finally:
        server.should_exit = True
        thread.join(10)
        redis_server.stop()


# Guarded: the intake process is spawned, and spawning imports the main module again
if __name__ == "__main__":
    main()
