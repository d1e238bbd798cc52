"""What a target job's converged tile costs the farm as the job grows in frames: the check that
``services.farm.targets.settle_converged`` makes each time a tile converges (every tile of the
job converged but one, which still renders), on the whole job's tiles and on one frame's (a
target job of frames settles each frame on its own).

    .venv/bin/python -m bench.settle_scale [--frames 1 10 40] [--size 1920 1080] [--tile 64]
                                           [--calls 3]

An embedded Redis (``services.launcher.EmbeddedRedis``); each job's plan is the farm's for a
target job of that size (passes growing from 8 to 256 samples, ``render.spp`` 1024), its tiles'
first three passes merged. "job-wide" reads the job's merged set and every tile's state (how a
job of one frame, or a job of frames stored before frames kept their own sums, is settled);
"its frame" one frame's passes (``SMISMEMBER``) and states (``HMGET``). A tile that converges
makes one such call, so a job's worth is about its tiles times it.
"""

from __future__ import annotations

import argparse
import time
import uuid


def measure(frames: list[int], size: tuple[int, int], tile: int, calls: int) -> list[dict]:
    import redis

    from services.farm.planner import Plan
    from services.farm.store import JobStore
    from services.farm.targets import settle_converged
    from services.launcher import EmbeddedRedis

    server = EmbeddedRedis().start()
    store = JobStore(redis.Redis.from_url(server.url), "settle")
    rows = []
    print(f"{'frames':>6} {'tiles':>7} {'tasks':>8} {'job-wide ms':>11} {'its frame ms':>12}",
          flush=True)
    try:
        for n in frames:
            plan = Plan(size[0], size[1], 1024, tile, 8, 256, n, 2)
            job = uuid.uuid4().hex
            store.create_job(job, "", 0, plan, "{}", target_error=0.01)
            merged = [f"{t}:{p}" for t in range(plan.n_tiles) for p in range(min(3, plan.n_passes))]
            for i in range(0, len(merged), 10_000):
                store.r.sadd(store.k("job", job, "merged"), *merged[i:i + 10_000])
            store.r.hset(store.k("job", job, "tile_state"),
                         mapping={str(t): "converged" for t in range(1, plan.n_tiles)})
            store.r.hset(store.k("job", job, "tile_state"), "0", "running")
            row = {"frames": n, "tiles": plan.n_tiles, "tasks": plan.n_tasks}
            for key, of_tile in (("job_ms", None), ("frame_ms", 0)):
                start = time.perf_counter()
                for _ in range(calls):
                    if settle_converged(store, lambda *a: None, job, of_tile):
                        raise AssertionError("a job with a tile rendering was settled")
                row[key] = 1e3 * (time.perf_counter() - start) / calls
            rows.append(row)
            print(f"{n:>6} {row['tiles']:>7} {row['tasks']:>8} {row['job_ms']:>11.1f} "
                  f"{row['frame_ms']:>12.1f}", flush=True)
            store.delete_job(job, statuses=("queued", "running"))
    finally:
        store.r.close()
        server.stop()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[1, 10, 40])
    parser.add_argument("--size", type=int, nargs=2, default=[1920, 1080])
    parser.add_argument("--tile", type=int, default=64)
    parser.add_argument("--calls", type=int, default=3)
    args = parser.parse_args(argv)
    measure(args.frames, tuple(args.size), args.tile, args.calls)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
