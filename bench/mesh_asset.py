"""A scene with a 1-million-triangle mesh submitted through ``lucent submit``'s path: the mesh
file uploaded as an asset, then the worker's fetch of it (issue #20).

    .venv/bin/python -m bench.mesh_asset [--triangles 1000000]

A grid of about ``--triangles`` triangles is written as binary PLY beside a copy of
``examples/cornell_box.json`` that names it by path. The API runs as ``lucent up`` runs it
(``uvicorn services.api.main:app`` in a process of its own, an embedded Redis, a temporary data
folder: the blob store). Timed, with ``services.client``:

- upload: ``scene_for_upload`` (SHA-256 of the file, ``HEAD /api/assets/…`` 404, ``POST
  /api/assets``), then the job's submission (``POST /api/jobs``: the API reads the asset from the
  blob store and checks the scene, the mesh parsed), then ``scene_for_upload`` again (the farm has
  the file: ``HEAD`` only);
- the worker's side: ``AssetCache.read`` cold (from the blob store into the worker's on-disk
  cache) and warm (from the cache), and ``load_scene`` with that reader (the mesh parsed).
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

from renderer.geometry.meshio import write_ply
from renderer.scene import load_scene
from services.client import Client, scene_for_upload
from services.farm.blobs import AssetCache, FileBlobStore
from services.launcher import EmbeddedRedis, free_port, terminate

ROOT = Path(__file__).resolve().parents[1]


def grid(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat square of about ``triangles`` triangles, 0.5 units wide, at the box's centre."""
    n = int(np.ceil(np.sqrt(triangles / 2))) + 1
    u = np.linspace(-0.25, 0.25, n, dtype=np.float32)
    x, y = np.meshgrid(u, u)
    vertices = np.stack([x.ravel(), y.ravel() + 0.5, np.zeros(n * n, np.float32)], axis=1)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    tri = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return vertices, tri.astype(np.int32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--triangles", type=int, default=1_000_000)
    args = ap.parse_args()
    work = tempfile.TemporaryDirectory(prefix="lucent-bench-")
    folder = Path(work.name)
    vertices, triangles = grid(args.triangles)
    write_ply(folder / "grid.ply", vertices, triangles)
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    material = next(iter(scene["materials"]))
    scene["objects"].append({"type": "mesh", "path": "grid.ply", "material": material})
    (folder / "scene.json").write_text(json.dumps(scene))
    size = (folder / "grid.ply").stat().st_size
    inline = len(json.dumps({"vertices": vertices.tolist(), "triangles": triangles.tolist()}))
    print(f"mesh: {len(triangles):,} triangles, {len(vertices):,} vertices; binary PLY "
          f"{size / 1e6:.1f} MB (inline JSON would be {inline / 1e6:.0f} MB)")

    redis_server = EmbeddedRedis().start()
    data = folder / "data"
    env = {**os.environ, "REDIS_URL": redis_server.url, "LUCENT_DATA_DIR": str(data),
           "LUCENT_KEY_PREFIX": f"bench-{uuid.uuid4().hex[:8]}", "LUCENT_API_TOKEN": ""}
    env.pop("DATABASE_URL", None)
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
        client = Client(base, timeout=300)
        t0 = time.perf_counter()
        sent = scene_for_upload(folder / "scene.json", client)
        t1 = time.perf_counter()
        job = client.submit(sent)
        t2 = time.perf_counter()
        assert scene_for_upload(folder / "scene.json", client) == sent
        t3 = time.perf_counter()
        print(f"upload (hash + HEAD + POST /api/assets): {t1 - t0:.2f} s")
        print(f"POST /api/jobs (the API reads and checks the mesh): {t2 - t1:.2f} s "
              f"-> job {job['id']} {job['status']}")
        print(f"second submission's upload step (HEAD only, the farm has it): "
              f"{(t3 - t2) * 1e3:.1f} ms")

        name = sent["objects"][-1]["asset"]
        cache = AssetCache(FileBlobStore(data / "blobs"), folder / "worker-cache", 2 * 1024**3)
        t0 = time.perf_counter()
        cache.read(name)
        t1 = time.perf_counter()
        cache.read(name)
        t2 = time.perf_counter()
        load_scene(sent, assets=cache.read)
        t3 = time.perf_counter()
        assert cache.fetched == 1
        print(f"worker fetch, cold (blob store -> on-disk cache): {(t1 - t0) * 1e3:.0f} ms; "
              f"warm (cache): {(t2 - t1) * 1e3:.0f} ms; load_scene with the mesh: "
              f"{t3 - t2:.2f} s")
    finally:
        terminate(api, 10.0)
        redis_server.stop()
        work.cleanup()


if __name__ == "__main__":
    main()
