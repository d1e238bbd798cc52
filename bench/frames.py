"""A sequence as one job of frames against the same frames as separate jobs: the time until
every frame has a first preview, and the whole sequence's throughput.

    .venv/bin/python -m bench.frames [--frames 24] [--size 160x120] [--spp 16] [--sweep 5]
                                     [--spp-per-pass N]

An embedded Redis, one worker node (``--concurrency 2``) and the API in-process. Two sequences of
the Cornell box, each run both ways (one job with ``frames``; one job a frame, submitted back to
back at the same priority):

- a camera path: ``--frames`` frames on an arc of 30 degrees about the box;
- a sweep: ``--sweep`` values of the white walls' albedo, 0.2 to 0.8.

"First preview of every frame": from the first submission until every frame has samples merged
(read from Redis every 20 ms); "all done": until every frame is done; throughput: frames / all
done. Every job of the run is a fresh seed (no cache of the workers helps one way).
``--spp-per-pass``: the first pass (the farm's default 8 when not given); the first preview of
every frame comes once every frame's first pass is merged, so its share of spp bounds it.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import tempfile
import time
import uuid
from pathlib import Path

import redis
from fastapi.testclient import TestClient

from services.api.main import create_app
from services.farm.frames import apply_patch
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, start_worker, terminate

ROOT = Path(__file__).resolve().parents[1]
POLL = 0.02


def camera_path(scene: dict, n: int) -> list[list[dict]]:
    """``n`` camera positions on an arc of 30 degrees about the look-at point."""
    px, py, pz = scene["camera"]["position"]
    lx, _, lz = scene["camera"]["look_at"]
    radius = math.hypot(px - lx, pz - lz)
    out = []
    for i in range(n):
        a = math.radians(-15 + 30 * i / max(n - 1, 1))
        out.append([{"op": "replace", "path": "/camera/position",
                     "value": [lx + radius * math.sin(a), py, lz + radius * math.cos(a)]}])
    return out


def albedo_sweep(n: int) -> list[list[dict]]:
    return [[{"op": "replace", "path": "/materials/white/albedo",
              "value": [0.2 + 0.6 * i / max(n - 1, 1)] * 3}] for i in range(n)]


def _wait(store: JobStore, previewed, done, timeout: float = 1800.0) -> tuple[float, float]:
    """Seconds until ``previewed()`` and until ``done()`` hold, from now."""
    t0 = time.perf_counter()
    first = None
    while True:
        now = time.perf_counter() - t0
        if first is None and previewed():
            first = now
        if done():
            return (first if first is not None else now), now
        assert now < timeout, "the jobs did not finish"
        time.sleep(POLL)


def one_job(client: TestClient, store: JobStore, scene: dict, frames: list,
            options: dict) -> tuple[float, float]:
    job = client.post("/api/jobs", json={"scene": scene, "frames": frames, **options})
    assert job.status_code == 201, job.text
    job_id, plan_tiles = job.json()["id"], job.json()["tiles"] // len(frames)

    def previewed() -> bool:
        samples = store.tile_samples(job_id)
        return all(any(samples.get(f * plan_tiles + t, 0) for t in range(plan_tiles))
                   for f in range(len(frames)))

    return _wait(store, previewed, lambda: store.get_status(job_id) in ("done", "failed"))


def separate_jobs(client: TestClient, store: JobStore, scene: dict, frames: list,
                  options: dict) -> tuple[float, float]:
    ids = []
    t0 = time.perf_counter()
    for patch in frames:
        r = client.post("/api/jobs", json={"scene": apply_patch(scene, patch), **options})
        assert r.status_code == 201, r.text
        ids.append(r.json()["id"])
    submit = time.perf_counter() - t0

    def metas():
        return store.get_jobs(ids)

    first, done = _wait(store, lambda: all(m.samples_merged for m in metas().values()),
                        lambda: all(m.status in ("done", "failed") for m in metas().values())
                        and len(metas()) == len(ids))
    return first + submit, done + submit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--sweep", type=int, default=5)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--concurrency", type=int, default=2)
    ap.add_argument("--spp-per-pass", type=int, default=None)
    args = ap.parse_args()
    width, height = map(int, args.size.split("x"))
    base = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    base["film"] = {"width": width, "height": height}
    base["render"]["spp"] = args.spp
    sequences = {f"camera path, {args.frames} frames": camera_path(base, args.frames),
                 f"albedo sweep, {args.sweep} values": albedo_sweep(args.sweep)}

    server = EmbeddedRedis().start()
    prefix = f"lucent-bench-{uuid.uuid4().hex[:8]}"
    seed = 1
    rows = []
    with tempfile.TemporaryDirectory() as data:
        # done jobs stay in Redis (not archived): the polling reads them there
        settings = Settings(redis_url=server.url, key_prefix=prefix, data_dir=Path(data),
                            api_token=None, archive_done=False)
        worker = start_worker(server.url, concurrency=args.concurrency, extra_env={
            "LUCENT_KEY_PREFIX": prefix, "LUCENT_API_TOKEN": ""})
        store = JobStore(redis.Redis.from_url(server.url), prefix)
        try:
            with TestClient(create_app(settings)) as client:
                # warm: the workers load the kernels before the first timed job
                warm = client.post("/api/jobs", json={"scene": base}).json()["id"]
                _wait(store, lambda: True, lambda: store.get_status(warm) == "done")
                for name, frames in sequences.items():
                    for how, run in (("one job of frames", one_job),
                                     ("separate jobs", separate_jobs)):
                        seed += 1
                        scene = copy.deepcopy(base)
                        scene["render"]["seed"] = seed
                        options = ({"spp_per_pass": args.spp_per_pass}
                                   if args.spp_per_pass else {})
                        first, done = run(client, store, scene, frames, options)
                        rows.append((name, how, first, done, len(frames) / done))
                        print(f"{name}: {how}: first preview of every frame {first:.2f} s, "
                              f"all done {done:.2f} s, {len(frames) / done:.2f} frames/s",
                              flush=True)
        finally:
            terminate(worker, 30.0)
            server.stop()
    print(f"\n{width}x{height}, {args.spp} spp, first pass {args.spp_per_pass or 'default'}, "
          f"one worker node of {args.concurrency} processes")
    print("| sequence | submitted as | first preview of every frame | all done | frames/s |")
    print("|---|---|---:|---:|---:|")
    for name, how, first, done, rate in rows:
        print(f"| {name} | {how} | {first:.2f} s | {done:.2f} s | {rate:.2f} |")


if __name__ == "__main__":
    main()
