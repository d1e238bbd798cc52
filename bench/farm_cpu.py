"""Where a farm job's CPU goes besides rendering: the CPU seconds of each process over one job.

    .venv/bin/python -m bench.farm_cpu [--scene examples/cornell_box.json] [--repeats 6]

An embedded Redis, one worker node of two single-threaded processes and the API in this process
(``bench.farm_speed``'s ``run_job``), warm. Around each job, the CPU seconds (user + system,
from ``/proc`` by ``psutil``) of Redis, the node's main process (Celery: messages,
acknowledgements, handing tasks to the pool), each pool process and this process (the service:
planning, sending the messages, its sweeper; and the polling), beside the render seconds the
workers count and the job's rendering share (render seconds over processes x done). Jobs run
back to back, so the service archives each job while the next renders.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from pathlib import Path

import psutil
import redis
from fastapi.testclient import TestClient

from bench.farm_speed import _wait, run_job
from services.api.main import create_app
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, start_worker, terminate

PROCESSES = 2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="examples/cornell_box.json")
    parser.add_argument("--repeats", type=int, default=6)
    args = parser.parse_args()
    body = {"scene": json.loads(Path(args.scene).read_text())}
    server = EmbeddedRedis().start()
    proc = start_worker(server.url, PROCESSES, 1, log=open(os.devnull, "w"),
                        extra_env={"LUCENT_KEY_PREFIX": "bench"})
    store = JobStore(redis.Redis.from_url(server.url), "bench")
    try:
        _wait(lambda: sum(w.get("state") == "idle" for w in store.workers()) >= PROCESSES,
              interval=0.2)
        with TestClient(create_app(Settings(redis_url=server.url, key_prefix="bench"))) as client:
            run_job(client, body, store)  # untimed: compiles the scene in every process
            node = psutil.Process(proc.pid)
            procs = {"redis": psutil.Process(server.proc.pid), "node main": node,
                     **{f"pool {i}": p for i, p in enumerate(node.children(recursive=True))},
                     "service": psutil.Process()}

            def cpu() -> dict[str, float]:
                return {k: p.cpu_times().user + p.cpu_times().system for k, p in procs.items()}

            shares = []
            for _ in range(args.repeats):
                c0, m0 = cpu(), store.metrics()
                r = run_job(client, body, store)
                c1, m1 = cpu(), store.metrics()
                render = m1["render_seconds"] - m0["render_seconds"]
                share = render / (PROCESSES * r["done"])
                shares.append(share)
                print(f"{r['tasks']} tasks, done {r['done']:.2f} s, render {render:.2f} s, "
                      f"rendering {100 * share:.1f} %; CPU s: "
                      + ", ".join(f"{k} {c1[k] - c0[k]:.3f}" for k in procs), flush=True)
            print(f"median rendering share {100 * statistics.median(shares):.1f} %")
    finally:
        terminate(proc, 30)
        store.r.close()
        server.stop()


if __name__ == "__main__":
    main()
