"""The farm's speed on this machine, with warm workers: submission to first preview and to
completion, per-task overhead, and prefork (N single-threaded processes) against one process
with N numba threads.

    .venv/bin/python -m bench.farm_speed [--scene examples/cornell_box.json] [--repeats 3]
        [--equal-passes] [--pass-growth 1 2] [--prefork-only] [--kernel packet|scalar]

Each configuration starts an embedded Redis and one worker node, waits until its processes are
warm (JIT loaded), renders the job once untimed (the scene compiled in every process), then
times ``--repeats`` submissions of the same job. "First pass begun" is when a worker began the
job's first pass (the job's ``started_at``), "first preview" when pass 0 of every tile has
merged (the whole frame at spp_per_pass samples). With several ``--pass-growth`` values, their
jobs take turns on the same worker node.

"Of local" is the local render's time over the job's (each job against the local render just
before it); "rendering" is the share of the worker processes' wall clock spent rendering
(render seconds over processes × done), the same comparison made within the job, so that the
drift of this machine's speed between the local render and the job (±20 %) does not enter it.
"""

from __future__ import annotations

import argparse
import contextlib
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
    """Submit ``body`` through the API and wait for the job to end. Completion is the job's own
    ``finished_at`` (written by the merge that counts its last task) less the moment of the
    POST, so the waiting need not be fine-grained: one HMGET of the job's hash in Redis every
    10 ms until the first preview (``store`` given; else ``GET /api/jobs/{id}``), every 100 ms
    after it. (The observer shares the machine's cores with the workers: at 100 Hz throughout,
    polling took ~50 ms of CPU a 1.5-s job, ~2 % of two cores; a dashboard polls once a
    second.)"""
    t0, wall0 = time.perf_counter(), time.time()
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
        # "": the hash is gone, the job archived once done (the records hold it)
        if status in ("done", "failed", "cancelled", ""):
            break
        time.sleep(0.01 if preview is None else 0.1)
    j = client.get(f"/api/jobs/{job['id']}").json()
    assert j["status"] == "done", j
    done = j["finished_at"] - wall0
    return {"started": j["started_at"] - wall0, "preview": min(preview or done, done),
            "done": done, "tasks": j["tasks_total"], "samples": j["samples_planned"]}


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
        # The share of the processes' wall clock spent rendering: what the job would be worth
        # against a local render of perfect scaling at the same speed of the machine, measured
        # within the job (this machine's speed drifts by ±20 % between runs, the local render
        # and the job each see their own)
        r["rendering"] = d["render_seconds"] / (r["done"] * processes)
        runs.append(r)
    return runs


_LOCAL = """
import json, sys, time
from renderer.render import render_buffer
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
cs = compile_scene(load_scene(json.loads(sys.stdin.read())))
kernel = sys.argv[1]
render_buffer(cs, 1, kernel=kernel)  # untimed: loads the kernels
t0 = time.perf_counter()
render_buffer(cs, kernel=kernel)
print(time.perf_counter() - t0)
"""


def local_seconds(scene: dict, threads: int, kernel: str = "scalar") -> float:
    """Seconds ``render_buffer`` takes for the whole ``scene`` in a fresh process with
    ``threads`` numba threads and ``kernel``, kernels loaded, the scene compiled (what ``lucent
    render`` spends rendering): the local render the farm is compared with."""
    out = subprocess.run([sys.executable, "-c", _LOCAL, kernel], input=json.dumps(scene), cwd=ROOT,
                         env={**os.environ, "NUMBA_NUM_THREADS": str(threads)},
                         capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def measure(name: str, concurrency: int, threads: int, body: dict, repeats: int,
            growths: list[int | None], kernel: str = "scalar") -> list[dict]:
    """The job ``repeats`` times for each pass growth of ``growths`` (None: the farm's
    default), taking turns on one worker node rendering with ``kernel``, each after a local
    render with the same kernel."""
    server = EmbeddedRedis().start()
    proc = start_worker(server.url, concurrency, threads, log=open(os.devnull, "w"),
                        extra_env={"LUCENT_KEY_PREFIX": "bench"}, kernel=kernel)
    store = JobStore(redis.Redis.from_url(server.url), "bench")
    runs: dict[int | None, list[dict]] = {g: [] for g in growths}
    local: dict[int | None, list[float]] = {g: [] for g in growths}
    try:
        _wait(lambda: sum(w.get("state") == "idle" for w in store.workers()) >= concurrency,
              interval=0.2)
        with contextlib.ExitStack() as stack:
            # the service plans the passes (LUCENT_PASS_GROWTH): one API per growth, one farm
            # (and for the workers' kernel: a scene the packet kernel covers gets larger passes)
            clients = {g: stack.enter_context(TestClient(create_app(Settings(
                redis_url=server.url, key_prefix="bench", worker_kernel=kernel,
                **({} if g is None else {"pass_growth": g}))))) for g in growths}
            for client in clients.values():
                run_job(client, body, store)  # untimed: compiles the scene in every process
            # each job after a local render on as many cores (the same drift of the machine)
            for _ in range(repeats):
                for g, client in clients.items():
                    local[g].append(local_seconds(body["scene"], concurrency * threads,
                                                  kernel))
                    runs[g] += timed_runs(client, store, body, 1, concurrency)
    finally:
        terminate(proc, 30)
        store.r.close()
        server.stop()
    out = []
    for g in growths:
        rs = runs[g]
        med = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
        med["local"] = statistics.median(local[g])
        # each job against the local render just before it
        med["of_local"] = statistics.median(t / r["done"]
                                            for t, r in zip(local[g], rs, strict=True))
        label = name if g is None else f"{name}, pass growth {g}"
        print(f"{label:>34}: first pass begun {1e3 * med['started']:.0f} ms after the POST, "
              f"preview {med['preview']:.2f} s, done {med['done']:.2f} s "
              f"({med['samples'] / med['done'] / 1e6:.2f} M samples/s; the local render "
              f"{med['local']:.2f} s, {100 * med['of_local']:.0f} % of it; rendering "
              f"{100 * med['rendering']:.0f} % of the processes' time), "
              f"{int(med['tasks'])} tasks, task overhead {med['overhead_ms']:.1f} ms in-task / "
              f"{med['wall_overhead_ms']:.1f} ms wall-clock per task", flush=True)
        out.append(med)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="examples/cornell_box.json")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--equal-passes", action="store_true",
                        help="equal passes of 32 px / 8 spp and 64 px / 16 spp (as measured "
                             "before passes grew) instead of the job's defaults")
    parser.add_argument("--pass-growth", type=int, nargs="+", default=[None],
                        help="the farm's pass growth (LUCENT_PASS_GROWTH) for the job, several "
                             "taking turns (default: the farm's default)")
    parser.add_argument("--kernel", choices=["scalar", "packet"], default="packet",
                        help="the kernel of the worker node and of the local render")
    parser.add_argument("--prefork-only", action="store_true",
                        help="leave out one process of N numba threads")
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
        measure(f"prefork {cores}x1 thread, {label}", cores, 1, body, args.repeats,
                args.pass_growth, args.kernel)
        if not args.prefork_only:
            measure(f"1 process x{cores} threads, {label}", 1, cores, body, args.repeats,
                    args.pass_growth, args.kernel)


if __name__ == "__main__":
    main()
