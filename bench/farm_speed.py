"""The farm's speed on this machine, with warm workers: submission to first preview and to
completion, per-task overhead, and prefork (N single-threaded processes) against one process
with N numba threads.

    .venv/bin/python -m bench.farm_speed [--scene examples/cornell_box.json] [--repeats 3]
        [--equal-passes]

Each configuration starts an embedded Redis and one worker node, waits until its processes are
warm (JIT loaded), renders the job once untimed (the scene compiled in every process), then
times ``--repeats`` submissions of the same job. "First preview" is when pass 0 of every tile
has merged (the whole frame at spp_per_pass samples).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, start_worker, terminate

ROOT = Path(__file__).resolve().parents[1]


def _wait(pred, timeout=600.0, interval=0.01):
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError
        time.sleep(interval)


def run_job(client: TestClient, body: dict, store: JobStore | None = None) -> dict:
    """Submit ``body`` through the API and wait for the job to end: every 10 ms, one HMGET of
    the job's hash in Redis when ``store`` is given, else ``GET /api/jobs/{id}``. (Through the
    in-process test client a status answer costs ~1.5 ms of CPU, which at 100 Hz takes ~15 % of
    a core from the workers on the same machine; a dashboard polls once a second.)"""
    t0 = time.perf_counter()
    job = client.post("/api/jobs", json=body).json()
    preview = None
    while True:
        if store is not None:
            status, merged = store.r.hmget(store.job_key(job["id"]), "status", "tasks_merged")
            status, merged = (status or b"").decode(), int(merged or 0)
        else:
            j = client.get(f"/api/jobs/{job['id']}").json()
            status, merged = j["status"], j["tasks_merged"]
        if preview is None and merged >= job["tiles"]:
            preview = time.perf_counter() - t0
        if status in ("done", "failed", "cancelled"):
            break
        time.sleep(0.01)
    done = time.perf_counter() - t0
    j = client.get(f"/api/jobs/{job['id']}").json()
    assert j["status"] == "done", j
    return {"preview": preview, "done": done, "tasks": j["tasks_total"],
            "samples": j["samples_planned"]}


def timed_runs(client: TestClient, store: JobStore, body: dict, repeats: int,
               processes: int) -> list[dict]:
    """``repeats`` runs of ``body``, each with its render seconds and per-task overheads, the
    farm's ``processes`` pool processes all rendering (``bench.scaling`` uses it as well)."""
    runs = []
    for _ in range(repeats):
        before = store.metrics()
        r = run_job(client, body, store)
        after = store.metrics()
        d = {k: after.get(k, 0) - before.get(k, 0) for k in after}
        r["render_s"] = d["render_seconds"]
        r["overhead_ms"] = 1e3 * (d["task_seconds"] - d["render_seconds"]) / d["tasks_done"]
        # Everything that is not rendering, per task, as the wall clock sees it
        # (broker round trips and idle time included).
        r["wall_overhead_ms"] = 1e3 * (r["done"] * processes - d["render_seconds"]) \
            / d["tasks_done"]
        runs.append(r)
    return runs


_LOCAL = """
import json, sys, time
from renderer.render import render_buffer
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
cs = compile_scene(load_scene(json.loads(sys.stdin.read())))
render_buffer(cs, 1)  # untimed: loads the kernels
t0 = time.perf_counter()
render_buffer(cs)
print(time.perf_counter() - t0)
"""


def local_seconds(scene: dict, threads: int) -> float:
    """Seconds ``render_buffer`` takes for the whole ``scene`` in a fresh process with
    ``threads`` numba threads, kernels loaded, the scene compiled (what ``lucent render`` spends
    rendering): the local render the farm is compared with."""
    out = subprocess.run([sys.executable, "-c", _LOCAL], input=json.dumps(scene), cwd=ROOT,
                         env={**os.environ, "NUMBA_NUM_THREADS": str(threads)},
                         capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def measure(name: str, concurrency: int, threads: int, body: dict, repeats: int) -> dict:
    server = EmbeddedRedis().start()
    settings = Settings(redis_url=server.url, key_prefix="bench")
    proc = start_worker(server.url, concurrency, threads, log=open(os.devnull, "w"),
                        extra_env={"LUCENT_KEY_PREFIX": "bench"})
    store = JobStore(redis.Redis.from_url(server.url), "bench")
    try:
        _wait(lambda: sum(w.get("state") == "idle" for w in store.workers()) >= concurrency,
              interval=0.2)
        with TestClient(create_app(settings)) as client:
            run_job(client, body, store)  # untimed: compiles the scene in every process
            # each job after a local render on as many cores (the same drift of the machine)
            runs, local = [], []
            for _ in range(repeats):
                local.append(local_seconds(body["scene"], concurrency * threads))
                runs += timed_runs(client, store, body, 1, concurrency)
    finally:
        terminate(proc, 30)
        store.r.close()
        server.stop()
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    med["local"] = statistics.median(local)
    print(f"{name:>34}: preview {med['preview']:.2f} s, done {med['done']:.2f} s "
          f"({med['samples'] / med['done'] / 1e6:.2f} M samples/s; the local render "
          f"{med['local']:.2f} s, {100 * med['local'] / med['done']:.0f} % of it), "
          f"{int(med['tasks'])} tasks, "
          f"task overhead {med['overhead_ms']:.1f} ms in-task / {med['wall_overhead_ms']:.1f} ms "
          f"wall-clock per task", flush=True)
    return med


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="examples/cornell_box.json")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--equal-passes", action="store_true",
                        help="equal passes of 32 px / 8 spp and 64 px / 16 spp (as measured "
                             "before passes grew) instead of the job's defaults")
    args = parser.parse_args()
    scene = json.loads(Path(args.scene).read_text())
    cores = os.cpu_count() or 1
    print(f"{args.scene}: {scene['film']['width']}x{scene['film']['height']}, "
          f"{scene['render']['spp']} spp, {cores} cores; medians of {args.repeats} runs")
    shapes = [("the default job", {})] if not args.equal_passes else [
        (f"tile {tile}/{per_pass} spp", {"tile_size": tile, "spp_per_pass": per_pass,
                                         "max_spp_per_pass": per_pass})
        for tile, per_pass in [(32, 8), (64, 16)]]
    for label, shape in shapes:
        body = {"scene": scene, **shape}
        measure(f"prefork {cores}x1 thread, {label}", cores, 1, body, args.repeats)
        measure(f"1 process x{cores} threads, {label}", 1, cores, body, args.repeats)


if __name__ == "__main__":
    main()
