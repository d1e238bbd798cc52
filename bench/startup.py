"""Start-up: a render process and a farm worker, with a warm and with a cold JIT cache.

    .venv/bin/python -m bench.startup [--repeats 3] [--no-cold] [--pool N]

- ``lucent render examples/cornell_box.json --spp 1``: the whole process (interpreter, imports,
  scene compile, kernel load or compile, one sample per pixel, the .npy written);
- ``lucent worker`` (Celery, one prefork process, one numba thread) on an embedded Redis: from the
  launch to the pool process's "warm in" log line, i.e. Celery is connected and the render kernel
  is loaded (``worker_process_init`` renders the warm-up scene) — the moment it can take a tile
  at full speed;
- with ``--pool N``, a cold node of N pool processes to the last one's "warm in", as it starts
  (the node compiles a cold cache once before its pool forks, ``worker.runtime.prewarm_cache``)
  and with ``LUCENT_PREWARM=0`` (each pool process compiles).

Warm: the shared numba cache (``LUCENT_CACHE_DIR`` or ~/.cache/lucent) already holds the kernels
(a first, untimed run fills it). Cold: a fresh empty ``LUCENT_CACHE_DIR``, so every kernel is
compiled; that figure is the JIT compile time users pay once per renderer version. Best of
``repeats`` for warm runs, one run for cold ones. Record results in docs/performance.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LUCENT = str(Path(sys.executable).with_name("lucent"))


def time_render(env: dict[str, str]) -> float:
    """Seconds for the whole ``lucent render --spp 1`` process."""
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        subprocess.run([LUCENT, "render", str(ROOT / "examples" / "cornell_box.json"), "-o",
                        f"{tmp}/x.npy", "--spp", "1", "-q"], env=env, check=True,
                       stdout=subprocess.DEVNULL)
        return time.perf_counter() - start


def time_worker(env: dict[str, str], redis_url: str, timeout: float = 300.0,
                processes: int = 1) -> float:
    """Seconds from launching a worker node of ``processes`` pool processes to the last one's
    "warm in" log line."""
    from services.launcher import terminate, worker_command, worker_env

    cmd = worker_command(processes, name=f"startup-bench-{os.getpid()}@%h", loglevel="INFO")
    start = time.perf_counter()
    full_env = worker_env(redis_url, 1, env)
    if "LUCENT_CACHE_DIR" in env:
        full_env.pop("NUMBA_CACHE_DIR", None)  # set by `import renderer` in this process
    proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        warm = 0
        for line in proc.stdout:
            warm += "warm in" in line
            if warm == processes:
                return time.perf_counter() - start
            if time.perf_counter() - start > timeout:
                break
        raise RuntimeError("the worker never reported it was warm")
    finally:
        terminate(proc, 10.0)
        proc.stdout.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-cold", action="store_true", help="skip the cold-cache runs")
    parser.add_argument("--pool", type=int, default=0, metavar="N",
                        help="also: a cold node of N pool processes, with the node's one compile "
                             "before the pool starts and without it (LUCENT_PREWARM=0)")
    args = parser.parse_args()
    from services.launcher import EmbeddedRedis

    warm_env = dict(os.environ)
    redis_url = os.environ.get("REDIS_URL")
    server = None
    if not redis_url:
        server = EmbeddedRedis().start()
        redis_url = server.url
    try:
        time_render(warm_env)  # fills the shared cache if it was empty
        rows = [("lucent render --spp 1, warm cache",
                 min(time_render(warm_env) for _ in range(args.repeats))),
                ("lucent worker to warm, warm cache",
                 min(time_worker({}, redis_url) for _ in range(args.repeats)))]
        if not args.no_cold:
            with tempfile.TemporaryDirectory() as cold:
                env = {**warm_env, "LUCENT_CACHE_DIR": cold}
                env.pop("NUMBA_CACHE_DIR", None)
                rows.append(("lucent render --spp 1, cold cache", time_render(env)))
            with tempfile.TemporaryDirectory() as cold:
                rows.append(("lucent worker to warm, cold cache",
                             time_worker({"LUCENT_CACHE_DIR": cold}, redis_url)))
        for prewarm in ("1", "0") if args.pool else ():
            with tempfile.TemporaryDirectory() as cold:
                label = "one compile first" if prewarm == "1" else "each process compiles"
                rows.append((f"{args.pool} processes to warm, cold, {label}",
                             time_worker({"LUCENT_CACHE_DIR": cold, "LUCENT_PREWARM": prewarm},
                                         redis_url, timeout=900.0, processes=args.pool)))
    finally:
        if server is not None:
            server.stop()
    for label, seconds in rows:
        print(f"{label:<36} {seconds:7.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
