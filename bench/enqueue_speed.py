"""How long the service takes to send a job's tasks to the broker (``services.farm.queue.enqueue``,
what ``POST /api/jobs`` spends after planning), by the number of tasks.

    .venv/bin/python -m bench.enqueue_speed [--tasks 60 1000 9180] [--repeats 3]

An embedded Redis, the service's Celery client, the messages of a job that does not exist sent to
a pool's queue no worker consumes (deleted after each run). 9180 tasks: a 1920x1080 frame of
1024 spp at the defaults (510 tiles of 64 px x 18 passes). Medians of ``--repeats`` runs after
an untimed one.
"""

from __future__ import annotations

import argparse
import statistics
import time

import redis

from services.farm.pools import queue_for
from services.farm.queue import celery_client, enqueue
from services.farm.settings import Settings
from services.launcher import EmbeddedRedis

TAGS = ("bench-enqueue",)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", type=int, nargs="+", default=[60, 1000, 9180])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    server = EmbeddedRedis().start()
    r = redis.Redis.from_url(server.url)
    try:
        app = celery_client(Settings(redis_url=server.url, key_prefix="bench"))
        job_id = "0" * 32
        enqueue(app, job_id, [(0, 0)], 0, TAGS)  # untimed: connects, declares
        for n in args.tasks:
            todo = [(i % 510, i // 510) for i in range(n)]
            wall, cpu = [], []
            for _ in range(args.repeats):
                r.delete(*r.keys(f"{queue_for(TAGS)}*") or ["-"])
                t0, c0 = time.perf_counter(), time.process_time()
                enqueue(app, job_id, todo, 0, TAGS)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            print(f"{n:>6} tasks: {1e3 * statistics.median(wall):7.1f} ms "
                  f"({1e6 * statistics.median(wall) / n:.0f} us a task), "
                  f"CPU {1e3 * statistics.median(cpu):7.1f} ms", flush=True)
    finally:
        r.close()
        server.stop()


if __name__ == "__main__":
    main()
