"""What a farm pass costs in Redis besides rendering: a worker's steps around the render, timed
one by one and counted in round trips.

    .venv/bin/python -m bench.pass_redis [--jobs 30] [--tile 64]

An embedded Redis and nothing rendering. Jobs of the default Cornell-box plan (320x240, 64 spp,
tiles of ``--tile`` px, passes 8, 16, 40), every pass of every tile in order, each as a worker
runs it (``worker/tasks.py``): ``begin_pass`` (the checks, the delivery counted),
``deliver`` (the buffer stored and merged; a buffer of random sums, the tile's size) and
``end_pass`` with the farm's counters. Medians and means over all passes, and the round trips of
a pass (writes to Redis, a pipeline one) counted on one pass that is not a job's first or last.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from collections.abc import Iterator

import numpy as np
import redis.connection

from renderer.film.buffer import SampleBuffer
from services.farm.passes import begin_pass, deliver, end_pass
from services.farm.planner import Plan
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis

STEPS = ("begin", "deliver", "end")


def _buffer(plan: Plan, tile: int, rng: np.random.Generator) -> SampleBuffer:
    x0, y0, w, h = plan.tile_rect(tile)
    buf = SampleBuffer.empty(x0, y0, w, h)
    buf.sum[:] = rng.random(buf.sum.shape)
    buf.sum_sq[:] = buf.sum ** 2
    buf.count[:] = 8
    return buf


def run_pass(store: JobStore, settings: Settings, plan: Plan, job_id: str, tile: int,
             pass_index: int, buf: SampleBuffer) -> tuple[float, float, float]:
    """One pass's Redis steps as a worker takes them; their seconds."""
    t0 = time.perf_counter()
    begin_pass(store, settings, job_id, tile, pass_index, holder="bench-w", node="bench-n")
    t1 = time.perf_counter()
    if not deliver(store, settings, job_id, tile, pass_index, buf):
        raise RuntimeError(f"pass {tile}:{pass_index} of {job_id} was not merged")
    t2 = time.perf_counter()
    end_pass(store, "bench-w", tasks_done=1, render_seconds=0.0, paths=0.0, task_seconds=0.0)
    return t1 - t0, t2 - t1, time.perf_counter() - t2


@contextlib.contextmanager
def counting_round_trips() -> Iterator[list[bytes]]:
    """What every Redis client of this process writes inside the block, one entry a round trip
    (a command, or a pipeline's commands in one write)."""
    sent: list[bytes] = []
    send = redis.connection.AbstractConnection.send_packed_command

    def counting(self, command, check_health=True):
        sent.append(b"".join(command) if isinstance(command, list) else command)
        return send(self, command, check_health)

    redis.connection.AbstractConnection.send_packed_command = counting  # type: ignore[method-assign]
    try:
        yield sent
    finally:
        redis.connection.AbstractConnection.send_packed_command = send  # type: ignore[method-assign]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=30)
    parser.add_argument("--tile", type=int, default=64)
    args = parser.parse_args()
    server = EmbeddedRedis().start()
    settings = Settings(redis_url=server.url, key_prefix="bench-pass")
    store = JobStore.from_url(server.url, settings.key_prefix)
    plan = Plan(width=320, height=240, spp=64, tile_size=args.tile, spp_per_pass=8,
                max_spp_per_pass=64, pass_growth=2)
    rng = np.random.default_rng(1)
    times: dict[str, list[float]] = {s: [] for s in (*STEPS, "total")}
    trips = 0
    try:
        for j in range(args.jobs + 1):
            job_id = f"{j:032x}"
            store.create_job(job_id, "bench", 0, plan, "{}")
            for tile, pass_index in plan.order():
                buf = _buffer(plan, tile, rng)
                if j == 0 and (tile, pass_index) == plan.order()[1]:
                    with counting_round_trips() as sent:
                        run_pass(store, settings, plan, job_id, tile, pass_index, buf)
                    trips = len(sent)
                    continue
                steps = run_pass(store, settings, plan, job_id, tile, pass_index, buf)
                if j == 0:
                    continue  # the first job loads the scripts and warms up: untimed
                for name, s in zip(STEPS, steps, strict=True):
                    times[name].append(s)
                times["total"].append(sum(steps))
            store.delete_job(job_id)
        print(f"{plan.width}x{plan.height}, {plan.spp} spp, tiles of {args.tile} px: "
              f"{plan.n_tasks} passes a job, {args.jobs} jobs; {trips} round trips a pass")
        for name, values in times.items():
            print(f"{name:>8}: median {1e3 * statistics.median(values):.3f} ms, "
                  f"mean {1e3 * statistics.mean(values):.3f} ms")
    finally:
        store.r.close()
        server.stop()


if __name__ == "__main__":
    main()
