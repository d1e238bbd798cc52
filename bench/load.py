"""Load: many clients at once against the farm on loopback, no 5xx and every job done.

    flock /tmp/lucent-cpu.lock .venv/bin/python -m bench.load \
        [--submissions 100] [--pollers 200] [--seconds 60] [--interval 1.0] [--workers 2]
    flock /tmp/lucent-cpu.lock .venv/bin/python -m bench.load --status \
        [--pollers 200] [--seconds 30] [--period 0.15] [--api-workers 1] [--render] [--no-etag]

``--status``: the polling path alone (issue #24's target), below. Without it:

An embedded Redis, ``--workers`` worker processes and ``uvicorn services.api.main:app`` in its own
process (``bench.dashboard_farm.DashboardFarm``), all on 127.0.0.1. Then, at once:

- ``--submissions`` clients each submit one small job (the Cornell box at 32x24, 16 spp: one
  task), all together;
- ``--pollers`` clients poll for ``--seconds``, each in turn ``GET /api/jobs/{id}`` (a job
  submitted so far), ``GET /api/jobs`` and ``GET /api/workers``, waiting ``--interval`` seconds
  between requests (the dashboard polls every 1-2 s; 0 makes every poller a closed loop), and
  at least one cycle past the last submission's answer;

and afterwards every job is waited for. The run fails (exit 1) on any 5xx, on any failed request,
or if a job does not finish ``done``. It prints p50/p99 latency per endpoint. The load generator
runs on the same 2 cores as the service, Redis and the workers: the latencies are an upper bound
of what the service alone would show.

``--status``: ``--jobs`` (20) small jobs are rendered first; then ``--pollers`` clients each ask
``GET /api/jobs/{id}`` (one of those jobs, in turn) every ``--period`` seconds, start to start (a
request that takes longer delays the next one, as a browser's timer would), for ``--seconds``,
sending the ``ETag`` of their last answer in ``If-None-Match`` as the dashboard does (``--no-etag``:
never). Each poller is one keep-alive connection written and read with asyncio streams (a few
tens of microseconds a request: httpx costs ten times that, and on a 2-core machine the load
generator's CPU is taken from the service). ``--render``: meanwhile a job that keeps both cores
busy renders (``--workers`` processes; the Cornell box at 320x240, 4096 spp), and one of the
polled jobs is that one. ``--api-workers``: uvicorn processes (``uvicorn --workers``). Prints the
requests per second answered, p50/p90/p99/max latency, the status codes, and the CPU the API
process(es) used per request; exits 1 on any failed request or any status but 200 and 304.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


def small_scene() -> dict:
    """The Cornell box at 32x24 pixels, 16 spp: one task with the default tile and pass."""
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 16
    return scene


@dataclass
class LoadResult:
    latencies: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    statuses: Counter = field(default_factory=Counter)
    errors: list[str] = field(default_factory=list)
    job_ids: list[str] = field(default_factory=list)
    final: dict[str, str] = field(default_factory=dict)
    drain_seconds: float = 0.0

    @property
    def server_errors(self) -> int:
        return sum(n for code, n in self.statuses.items() if code >= 500)

    def ok(self, submissions: int) -> bool:
        return (not self.server_errors and not self.errors and len(self.job_ids) == submissions
                and all(s == "done" for s in self.final.values())
                and len(self.final) == submissions)

    def percentiles(self, endpoint: str) -> tuple[int, float, float]:
        """(requests, p50 ms, p99 ms) of an endpoint."""
        values = sorted(self.latencies[endpoint])
        q = statistics.quantiles(values, n=100, method="inclusive") if len(values) > 1 else \
            values * 99
        return len(values), 1e3 * q[49], 1e3 * q[98]

    def report(self) -> str:
        lines = [f"{'endpoint':<22} {'requests':>8} {'p50 ms':>8} {'p99 ms':>8}"]
        for endpoint in sorted(self.latencies):
            n, p50, p99 = self.percentiles(endpoint)
            lines.append(f"{endpoint:<22} {n:>8} {p50:>8.1f} {p99:>8.1f}")
        lines.append(f"status codes: {dict(sorted(self.statuses.items()))}; "
                     f"failed requests: {len(self.errors)}")
        done = sum(s == "done" for s in self.final.values())
        lines.append(f"jobs: {len(self.job_ids)} submitted, {done} done, "
                     f"all done {self.drain_seconds:.1f} s after the polling ended")
        return "\n".join(lines)


async def run_load(base_url: str, submissions: int, pollers: int, seconds: float,
                   interval: float = 1.0, scene: dict | None = None, token: str | None = None,
                   job_timeout: float = 300.0) -> LoadResult:
    """Submit ``submissions`` jobs and run ``pollers`` pollers for ``seconds``, all at once;
    then wait (at most ``job_timeout`` s) for every job to end."""
    scene = scene or small_scene()
    result = LoadResult()
    headers = {"Authorization": f"Bearer {token}"} if token else {}

    def new_client() -> httpx.AsyncClient:
        # One client (one connection) per simulated user, as browsers would have: a shared pool
        # of hundreds of connections costs httpx more CPU per request than the service spends.
        # Idle connections are dropped before uvicorn's 5 s keep-alive timeout closes them: at
        # equal timeouts a request sent on a connection the server is closing fails.
        return httpx.AsyncClient(base_url=base_url, headers=headers, timeout=60.0,
                                 limits=httpx.Limits(max_connections=1, keepalive_expiry=2.0))

    async def call(client: httpx.AsyncClient, endpoint: str, method: str, url: str,
                   **kwargs) -> httpx.Response | None:
        t0 = time.perf_counter()
        try:
            r = await client.request(method, url, **kwargs)
        except httpx.HTTPError as err:
            result.errors.append(f"{method} {url}: {err!r}")
            return None
        result.latencies[endpoint].append(time.perf_counter() - t0)
        result.statuses[r.status_code] += 1
        return r

    async def submit(i: int) -> None:
        async with new_client() as client:
            r = await call(client, "POST /api/jobs", "POST", "/api/jobs",
                           json={"scene": scene, "name": f"load-{i}"})
        if r is not None and r.status_code == 201:
            result.job_ids.append(r.json()["id"])
        elif r is not None:
            result.errors.append(f"submission {i}: {r.status_code} {r.text[:200]}")

    submitted = asyncio.Event()  # every submission answered

    async def submit_all() -> None:
        await asyncio.gather(*(submit(i) for i in range(submissions)))
        submitted.set()

    async def poll(i: int, stop: float) -> None:
        turn = i  # pollers start at different places of the cycle
        after = 0  # turns since every submission was answered
        async with new_client() as client:
            # Until the time is up, and at least one whole cycle (a job, the list, the workers)
            # past the burst of submissions: on a slow machine the burst can outlast the
            # polling time, and the job endpoint would never be polled.
            while time.perf_counter() < stop or after < 3:
                if submitted.is_set():
                    after += 1
                kind = turn % 3
                if kind == 0 and result.job_ids:
                    job_id = result.job_ids[turn % len(result.job_ids)]
                    await call(client, "GET /api/jobs/{id}", "GET", f"/api/jobs/{job_id}")
                elif kind == 1:
                    await call(client, "GET /api/jobs", "GET", "/api/jobs", params={"limit": 20})
                else:
                    await call(client, "GET /api/workers", "GET", "/api/workers")
                turn += 1
                if interval:
                    await asyncio.sleep(interval)

    stop = time.perf_counter() + seconds
    await asyncio.gather(submit_all(), *(poll(i, stop) for i in range(pollers)))

    # Every job to its end (not counted in the latencies).
    t0 = time.perf_counter()
    pending = set(result.job_ids)
    async with new_client() as client:
        while pending and time.perf_counter() - t0 < job_timeout:
            for job_id in list(pending):
                r = await client.get(f"/api/jobs/{job_id}")
                result.statuses[r.status_code] += 1
                status = r.json()["status"] if r.status_code == 200 else f"http {r.status_code}"
                if status not in ("queued", "running"):
                    result.final[job_id] = status
                    pending.discard(job_id)
            if pending:
                await asyncio.sleep(0.5)
    result.drain_seconds = time.perf_counter() - t0
    return result


@dataclass
class PollResult:
    latencies: list[float] = field(default_factory=list)
    statuses: Counter = field(default_factory=Counter)
    errors: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.errors and set(self.statuses) <= {200, 304} and bool(self.latencies)

    def report(self) -> str:
        values = sorted(self.latencies)
        q = statistics.quantiles(values, n=100, method="inclusive") if len(values) > 1 else \
            values * 99
        return (f"{len(values)} answers in {self.seconds:.1f} s: {len(values) / self.seconds:.0f} "
                f"requests/s; latency p50 {1e3 * q[49]:.1f} ms, p90 {1e3 * q[89]:.1f} ms, "
                f"p99 {1e3 * q[98]:.1f} ms, max {1e3 * values[-1]:.1f} ms; status codes "
                f"{dict(sorted(self.statuses.items()))}; failed requests {len(self.errors)}")


async def _get(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
               request: bytes) -> tuple[int, dict[str, str], bytes]:
    """One HTTP/1.1 request on a keep-alive connection: (status, headers, body)."""
    writer.write(request)
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split(" ", 2)[1])
    headers = {}
    for line in lines[1:]:
        if line:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
    body = await reader.readexactly(int(headers.get("content-length", 0)))
    return status, headers, body


async def run_pollers(host: str, port: int, job_ids: list[str], pollers: int, seconds: float,
                      period: float, etag: bool = True, token: str | None = None) -> PollResult:
    """``pollers`` clients, each on one keep-alive connection, asking ``GET /api/jobs/{id}``
    (poller i: job i mod len(job_ids)) every ``period`` seconds, start to start, for
    ``seconds``; with ``etag``, sending back the last answer's ETag in ``If-None-Match``."""
    result = PollResult()
    loop = asyncio.get_running_loop()
    auth = f"Authorization: Bearer {token}\r\n" if token else ""
    start = loop.time() + 0.5
    stop = start + seconds

    async def poll(i: int) -> None:
        job_id = job_ids[i % len(job_ids)]
        connection = await asyncio.open_connection(host, port)
        last_etag = ""
        tick = start + period * i / pollers  # spread over the period
        while True:
            if tick > loop.time():
                await asyncio.sleep(tick - loop.time())
            if loop.time() >= stop:
                break
            tick = max(tick + period, loop.time())  # late: the next one at once, no catch-up
            match = f"If-None-Match: {last_etag}\r\n" if etag and last_etag else ""
            request = (f"GET /api/jobs/{job_id} HTTP/1.1\r\nHost: {host}\r\n{auth}{match}"
                       "\r\n").encode()
            t0 = time.perf_counter()
            try:
                status, headers, _ = await _get(*connection, request)
            except (OSError, asyncio.IncompleteReadError, ValueError) as err:
                result.errors.append(f"GET /api/jobs/{job_id}: {err!r}")
                connection[1].close()
                connection = await asyncio.open_connection(host, port)
                continue
            result.latencies.append(time.perf_counter() - t0)
            result.statuses[status] += 1
            last_etag = headers.get("etag", last_etag)
        connection[1].close()

    t0 = time.perf_counter()
    await asyncio.gather(*(poll(i) for i in range(pollers)))
    result.seconds = time.perf_counter() - t0 - 0.5
    return result


def status_main(args: argparse.Namespace) -> int:
    """``--status``: the polling path (see the module's docstring)."""
    import psutil

    from bench.dashboard_farm import DashboardFarm

    with DashboardFarm(workers=args.workers, api_workers=args.api_workers) as farm, \
            httpx.Client(base_url=farm.url, timeout=60) as client:
        assert farm.server is not None
        scene = small_scene()
        job_ids = [client.post("/api/jobs", json={"scene": scene, "name": f"poll-{i}"}
                               ).json()["id"] for i in range(args.jobs)]
        for job_id in job_ids:
            assert farm.wait(client, job_id)["status"] == "done"
        if args.render:
            big = farm.submit(client, "cornell_box", film={"width": 320, "height": 240},
                              spp=4096, name="both cores")
            farm.wait(client, big["id"], statuses=("running",))
            job_ids[0] = big["id"]
        api = psutil.Process(farm.server.pid)
        processes = [api, *api.children(recursive=True)]
        cpu0, t0 = sum(sum(p.cpu_times()[:2]) for p in processes), time.perf_counter()
        psutil.cpu_percent()
        result = asyncio.run(run_pollers("127.0.0.1", farm.port, job_ids, args.pollers,
                                         args.seconds, args.period, etag=not args.no_etag))
        wall, machine = time.perf_counter() - t0, psutil.cpu_percent()
        api_cpu = sum(sum(p.cpu_times()[:2]) for p in processes) - cpu0
        rendering = ""
        if args.render:
            job = client.get(f"/api/jobs/{job_ids[0]}").json()
            rendering = (f"; the render was {job['status']} at {job['progress']:.0%} "
                         f"({job['samples_per_second'] or 0:,.0f} samples/s)")
            client.delete(f"/api/jobs/{job_ids[0]}")
    print(f"{args.pollers} pollers every {args.period:g} s for {args.seconds:g} s "
          f"(offered {args.pollers / args.period:.0f} requests/s), "
          f"{'with' if not args.no_etag else 'without'} If-None-Match, {args.jobs} jobs, "
          f"{args.api_workers} API process(es), {args.workers} worker processes{rendering}")
    print(result.report())
    n = max(len(result.latencies), 1)
    print(f"the API used {api_cpu / wall:.2f} of a core ({1e3 * api_cpu / n:.2f} ms a request), "
          f"the machine {machine:.0f}% of its {psutil.cpu_count()} cores")
    for error in result.errors[:10]:
        print("error:", error)
    return 0 if result.ok else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--submissions", type=int, default=100)
    parser.add_argument("--pollers", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--interval", type=float, default=1.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--status", action="store_true",
                        help="the polling path alone: GET /api/jobs/{id} at a fixed rate")
    parser.add_argument("--period", type=float, default=0.15,
                        help="--status: seconds between one poller's requests, start to start")
    parser.add_argument("--jobs", type=int, default=20, help="--status: jobs polled")
    parser.add_argument("--api-workers", type=int, default=1, help="uvicorn processes")
    parser.add_argument("--render", action="store_true",
                        help="--status: a render keeps both cores busy meanwhile")
    parser.add_argument("--no-etag", action="store_true",
                        help="--status: never send If-None-Match")
    args = parser.parse_args(argv)
    if args.status:
        return status_main(args)

    import psutil

    from bench.dashboard_farm import DashboardFarm

    with DashboardFarm(workers=args.workers) as farm:
        assert farm.server is not None
        api, me = psutil.Process(farm.server.pid), psutil.Process()
        api0, me0, t0 = sum(api.cpu_times()[:2]), sum(me.cpu_times()[:2]), time.perf_counter()
        psutil.cpu_percent()
        result = asyncio.run(run_load(farm.url, args.submissions, args.pollers, args.seconds,
                                      args.interval))
        wall, machine = time.perf_counter() - t0, psutil.cpu_percent()
        api_cpu, my_cpu = sum(api.cpu_times()[:2]) - api0, sum(me.cpu_times()[:2]) - me0
    print(f"{args.submissions} submissions, {args.pollers} pollers for {args.seconds:g} s "
          f"(interval {args.interval:g} s), {args.workers} worker processes, 127.0.0.1")
    print(result.report())
    polls = sum(len(v) for k, v in result.latencies.items() if k.startswith("GET"))
    print(f"status requests: {polls / args.seconds:.0f}/s; over the {wall:.1f} s run the API "
          f"process used {api_cpu / wall:.2f} of a core, this load generator {my_cpu / wall:.2f}, "
          f"the machine {machine:.0f}% of its {psutil.cpu_count()} cores")
    for error in result.errors[:10]:
        print("error:", error)
    return 0 if result.ok(args.submissions) else 1


if __name__ == "__main__":
    sys.exit(main())
