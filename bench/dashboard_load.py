"""What the dashboard costs the service: requests per second the status endpoints serve, and the
CPU time of the API process with one dashboard page open against none.

    .venv/bin/python -m bench.dashboard_load [--rps-seconds 5] [--clients 8] [--seconds 60]

1. Requests per second: ``--clients`` threads, each with its own keep-alive ``httpx.Client``, call
   one endpoint in a loop for ``--rps-seconds`` against 127.0.0.1 (the client runs on the same
   machine and takes CPU from the server: the numbers are a floor). The farm holds a few jobs.
2. CPU: the ``uvicorn`` process's user + system time (psutil) over ``--seconds`` with no page
   open, then with one headless Chromium page on the Jobs page, then on the page of a job being
   rendered (the worst case: its preview changes with every merge and is fetched again).
"""

from __future__ import annotations

import argparse
import threading
import time

import httpx
import psutil

from bench.dashboard_farm import CHROMIUM, CHROMIUM_ARGS, DashboardFarm


def requests_per_second(url: str, path: str, clients: int, seconds: float) -> tuple[float, float]:
    """(requests/s, median latency in ms) of ``clients`` threads calling GET ``path``."""
    counts = [0] * clients
    latencies: list[list[float]] = [[] for _ in range(clients)]
    stop = time.perf_counter() + seconds

    def loop(i: int) -> None:
        with httpx.Client(base_url=url, timeout=10) as c:
            while time.perf_counter() < stop:
                t0 = time.perf_counter()
                r = c.get(path)
                latencies[i].append(time.perf_counter() - t0)
                assert r.status_code == 200, (path, r.status_code)
                counts[i] += 1

    t0 = time.perf_counter()
    threads = [threading.Thread(target=loop, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - t0
    lat = sorted(x for xs in latencies for x in xs)
    return sum(counts) / elapsed, 1000 * lat[len(lat) // 2]


def cpu_seconds(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def cpu_share(proc: psutil.Process, seconds: float, page=None) -> float:
    """Share of one core the process used over ``seconds`` of wall time (waiting in Playwright
    when a page is given, so that its events are delivered)."""
    c0, t0 = cpu_seconds(proc), time.perf_counter()
    if page is None:
        time.sleep(seconds)
    else:
        page.wait_for_timeout(seconds * 1000)
    return (cpu_seconds(proc) - c0) / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rps-seconds", type=float, default=5.0)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    with DashboardFarm(workers=2) as farm, httpx.Client(base_url=farm.url, timeout=60) as api:
        half = {"width": 160, "height": 120}
        jobs = [farm.submit(api, name, film=half, spp=16)
                for name in ("cornell_box", "glass_sphere", "mirror_phong")]
        for job in jobs:
            farm.wait(api, job["id"])
        big = jobs[0]  # 160x120 in 32 px tiles: 20 tiles in its status
        print(f"farm: {farm.url}, {len(jobs)} jobs, job {big['id'][:8]} has {big['tiles']} tiles")

        print(f"\n## Requests per second ({args.clients} clients, {args.rps_seconds:g} s each)\n")
        print("| endpoint | requests/s | median ms |\n|---|---:|---:|")
        for path in ("/healthz", "/api/workers", "/api/jobs", f"/api/jobs/{big['id']}"):
            rps, med = requests_per_second(farm.url, path, args.clients, args.rps_seconds)
            shown = path.replace(big["id"], "{id}")
            print(f"| `GET {shown}` | {rps:,.0f} | {med:.1f} |", flush=True)

        server = psutil.Process(farm.server.pid)
        print(f"\n## CPU of the API process ({args.seconds:g} s each)\n")
        print("| pages open | share of one core |\n|---|---:|")
        print(f"| none (idle: the sweeper) | {100 * cpu_share(server, args.seconds):.2f} % |",
              flush=True)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1366, "height": 900})
            page.goto(f"{farm.url}/#/jobs")
            page.wait_for_selector("#jobs-count:not(:empty)")
            print(f"| Jobs page ({len(jobs)} jobs) | "
                  f"{100 * cpu_share(server, args.seconds, page):.2f} % |", flush=True)
            # A job that renders for longer than the window: 640x480 at 128 spp.
            running = farm.submit(api, "translucent_sphere", film={"width": 640, "height": 480},
                                  spp=128, spp_per_pass=4)
            page.goto(f"{farm.url}/#/job/{running['id']}")
            page.wait_for_selector("#preview[data-version]", timeout=60_000)
            images: list[str] = []
            page.on("response", lambda r: images.append(r.url) if "/image." in r.url else None)
            share = cpu_share(server, args.seconds, page)
            status = api.get(f"/api/jobs/{running['id']}").json()
            print(f"| job page of a running job ({len(images)} previews fetched, job "
                  f"{100 * status['progress']:.0f} % at the end) | {100 * share:.2f} % |")
            page.close()
            # Baseline again with the render still going (the workers load the machine too).
            idle = cpu_share(server, min(args.seconds, 20.0))
            print(f"| none, the job still rendering ({min(args.seconds, 20.0):g} s) | "
                  f"{100 * idle:.2f} % |")
            browser.close()
            api.delete(f"/api/jobs/{running['id']}")


if __name__ == "__main__":
    main()
