"""A worker node SIGKILLed mid-pass: how long until its pass is sent again and rendered elsewhere.

    flock /tmp/lucent-cpu.lock .venv/bin/python -m bench.worker_loss [--runs 5] [--heartbeat 2]

An embedded Redis, two worker nodes of one process each (real Celery workers) and the API's
sweeper in this process (``create_app`` under FastAPI's TestClient, sweeping every second as
deployed). Each run submits a job of one pass that renders for seconds (the Cornell box at
64x64, 2048 spp, one tile, one pass); once a node's process has begun it, that node's main
process is SIGKILLed (its pool process dies with it: Celery sets ``PDEATHSIG``), as a machine
losing power would. Measured from the kill: the sweeper sending the pass again (``lost_requeues``
counted), the other node beginning it (its second try counted), and the job done. The stall time
(300 s) and the visibility timeout (900 s) are set far above, so that only the lost-worker rule
(``services/farm/lost_workers.py``) can bring the pass back this soon. The killed node is started
again before the next run.

Expected: the heartbeat expires 3 intervals after the last beat, at most that long after the
kill, and the next sweep (every ``sweep_interval``) re-queues: at most 3 x heartbeat + 1 s.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# The other ways a lost pass comes back, set far above what is measured here.
STALL_TIMEOUT = 300.0
VISIBILITY_TIMEOUT = 900.0
TIMINGS = {"stall_timeout": STALL_TIMEOUT, "visibility_timeout": VISIBILITY_TIMEOUT,
           "task_soft_time_limit": 120.0, "task_time_limit": 150.0}


def long_pass_scene(spp: int = 2048) -> dict:
    """The Cornell box at 64x64: one 64-px tile, one pass of ``spp`` samples (seconds)."""
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 64, "height": 64}
    scene["render"]["spp"] = spp
    return copy.deepcopy(scene)


@dataclass
class Loss:
    """Seconds from the SIGKILL to each event of one run."""

    requeued: float  # the sweeper sent the pass again
    begun: float  # another node began it
    done: float  # the job was done
    heartbeat: float


class TwoNodes:
    """Two worker nodes (one process each) on one Redis and key prefix."""

    def __init__(self, redis_url: str, prefix: str, heartbeat: float, log_dir: Path):
        self.redis_url, self.prefix, self.heartbeat, self.log_dir = (redis_url, prefix,
                                                                     heartbeat, log_dir)
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str) -> None:
        from services.launcher import start_worker

        env = {f"LUCENT_{k.upper()}": str(v) for k, v in TIMINGS.items()}
        env.update({"LUCENT_KEY_PREFIX": self.prefix, "LUCENT_API_TOKEN": "",
                    "LUCENT_HEARTBEAT_INTERVAL": str(self.heartbeat)})
        with open(self.log_dir / f"{name}.log", "a") as log:
            self.procs[name] = start_worker(self.redis_url, 1, 1, name=f"{name}-{self.prefix}@%h",
                                            extra_env=env, log=log)

    def node_of(self, pid: int) -> str | None:
        import psutil

        for name, proc in self.procs.items():
            if proc.poll() is None and pid in {c.pid for c in psutil.Process(proc.pid).children()}:
                return name
        return None

    def stop(self) -> None:
        from services.launcher import terminate

        for proc in self.procs.values():
            terminate(proc, 10.0)


def _watch(conditions: dict, timeout: float, interval: float = 0.02) -> dict[str, float]:
    """Poll every condition until each has held once; the monotonic time each first held."""
    seen: dict[str, float] = {}
    deadline = time.monotonic() + timeout
    while len(seen) < len(conditions):
        for name, condition in conditions.items():
            if name not in seen and condition():
                seen[name] = time.monotonic()
        if time.monotonic() > deadline:
            missing = [name for name in conditions if name not in seen]
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {missing}")
        time.sleep(interval)
    return seen


def _live_processes(store) -> int:
    return sum(w.get("state") in ("idle", "busy") for w in store.workers())


def lose_a_worker(api, store, nodes: TwoNodes, scene: dict, timeout: float = 120.0) -> Loss:
    """One run: submit the one-pass job, SIGKILL the node that begins it, time the recovery.
    ``api``: a TestClient of the app (its sweeper running) on the nodes' Redis and prefix."""
    _watch({"two warm worker processes": lambda: _live_processes(store) >= 2}, 240.0, 0.1)
    r = api.post("/api/jobs", json={"scene": scene, "tile_size": 64,
                                    "spp_per_pass": scene["render"]["spp"]})
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    assert r.json()["tasks_total"] == 1
    holders: list[int] = []

    def begun() -> bool:
        holders.extend(int(w["pid"]) for w in store.workers() if w.get("state") == "busy"
                       and w.get("current_task", "").startswith(job_id))
        return bool(holders)

    _watch({"a worker process to begin the pass": begun}, timeout)
    victim = nodes.node_of(holders[0])
    assert victim is not None, f"no node has the pool process {holders[0]}"
    requeues = store.metrics().get("lost_requeues", 0.0)
    nodes.procs[victim].kill()  # SIGKILL; the pool process gets SIGKILL from PDEATHSIG
    t0 = time.monotonic()
    nodes.procs[victim].wait()
    seen = _watch({
        "requeued": lambda: store.metrics().get("lost_requeues", 0.0) > requeues,
        "begun": lambda: store.attempts(job_id, 0, 0) >= 2,
        "done": lambda: store.get_status(job_id) in ("done", "failed", "cancelled"),
    }, timeout)
    assert store.get_status(job_id) == "done", store.get_job(job_id)
    nodes.start(victim)  # for the next run
    return Loss(seen["requeued"] - t0, seen["begun"] - t0, seen["done"] - t0, nodes.heartbeat)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--heartbeat", type=float, default=2.0,
                        help="LUCENT_HEARTBEAT_INTERVAL of the workers (default 2 s, deployed)")
    parser.add_argument("--spp", type=int, default=2048)
    args = parser.parse_args(argv)

    from fastapi.testclient import TestClient

    from services.api.main import create_app
    from services.farm.settings import Settings
    from services.farm.store import JobStore
    from services.launcher import EmbeddedRedis

    prefix = f"lucent-loss-{uuid.uuid4().hex[:8]}"
    server = EmbeddedRedis().start()
    log_dir = Path(tempfile.mkdtemp(prefix="lucent-loss-"))
    nodes = TwoNodes(server.url, prefix, args.heartbeat, log_dir)
    store = JobStore.from_url(server.url, prefix)
    settings = Settings(redis_url=server.url, key_prefix=prefix, api_token=None,
                        heartbeat_interval=args.heartbeat, **TIMINGS)
    losses = []
    try:
        nodes.start("a")
        nodes.start("b")
        with TestClient(create_app(settings)) as api:
            for run in range(args.runs):
                loss = lose_a_worker(api, store, nodes, long_pass_scene(args.spp))
                losses.append(loss)
                print(f"run {run + 1}: re-queued {loss.requeued:.2f} s after the kill, begun "
                      f"again {loss.begun:.2f} s, job done {loss.done:.2f} s", flush=True)
    finally:
        store.close()
        nodes.stop()
        server.stop()
    timeout = 3 * args.heartbeat
    print(f"heartbeat every {args.heartbeat:g} s (timeout {timeout:g} s), sweep every "
          f"{settings.sweep_interval:g} s; {len(losses)} runs; worker logs in {log_dir}")
    for name in ("requeued", "begun", "done"):
        values = [getattr(loss, name) for loss in losses]
        print(f"{name:>9}: median {statistics.median(values):.2f} s, max {max(values):.2f} s "
              f"({max(values) / timeout:.2f} heartbeat timeouts)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
