"""The same job with 1, 2, … N worker processes: completion time, samples/s, speedup, parallel
efficiency and per-task overhead, for a sweep of tile sizes and pass sizes; with ``--netns`` every
worker node runs in its own network namespace, so that every byte between it and Redis crosses a
real network interface (a veth pair).

    flock /tmp/lucent-cpu.lock .venv/bin/python -m bench.scaling \\
        [--scene examples/cornell_box.json] [--spp N] [--workers 1,2] [--tiles 32,64] \\
        [--passes 8,16,8-64] [--repeats 3] [--per-node 1] [--netns [--subnet 10.213.0.0/24]] \\
        [--csv out.csv]

For each worker count the benchmark starts an embedded Redis and ``N / --per-node`` worker nodes
(``celery … worker --concurrency per-node``, one numba thread a process, as ``lucent worker``
runs them), waits until every process is warm, renders the job once untimed, then times
``--repeats`` submissions of each (tile, pass) shape through the in-process API
(``bench.farm_speed``'s ``run_job`` and ``timed_runs``: the same definitions of completion and
overhead). Speedup is against the smallest worker count of the same shape, efficiency is
speedup × that count / N. Before every timed job the same scene is rendered locally, in a fresh
process with N numba threads (``render_buffer``, kernels loaded, untimed warm-up first): "of
local" is that render's time over the job's, submission to done (issue #23's aim: at least 90 %
with two workers).

``--netns`` (root and iproute2): a bridge on the host with the first address of ``--subnet``,
Redis bound to that address only, and per node a namespace ``lucent-scaling-<pid>-<i>`` holding one
end of a veth pair whose other end is on the bridge. The API stays in the host namespace. The
benchmark checks that Redis sees one client address per namespace and reports the bytes that
crossed the veths per job. Namespaces, veths and the bridge are removed on exit, also on Ctrl-C,
SIGTERM or an exception (a SIGKILLed run leaves them: ``ip netns list``, ``ip link``).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import ipaddress
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import redis
from fastapi.testclient import TestClient

from bench.farm_speed import _wait, local_seconds, run_job, timed_runs
from services.api.main import create_app
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, _die_with_parent, worker_command, worker_env

ROOT = Path(__file__).resolve().parents[1]
KEY_PREFIX = "bench"


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


class NetnsNetwork:
    """``nodes`` network namespaces, each joined to a host bridge by a veth pair.

    The bridge holds the first host address of ``subnet`` (Redis binds to it), namespace ``i``
    the ``i + 2``-th. ``teardown`` removes everything ``setup`` created, whatever state setup
    stopped in; both are idempotent, and the class is a context manager.
    """

    def __init__(self, nodes: int, subnet: str = "10.213.0.0/24", tag: str | None = None):
        net = ipaddress.IPv4Network(subnet)
        hosts = list(net.hosts())
        if nodes + 1 > len(hosts):
            raise ValueError(f"{subnet} has room for {len(hosts) - 1} nodes, not {nodes}")
        self.prefixlen = net.prefixlen
        self.host_address = str(hosts[0])
        self.node_addresses = [str(a) for a in hosts[1:nodes + 1]]
        tag = tag or str(os.getpid() % 100_000)
        # Interface names are at most 15 bytes.
        self.bridge = f"lcb{tag}"
        self.namespaces = [f"lucent-scaling-{tag}-{i}" for i in range(nodes)]
        self.host_veths = [f"lc{tag}h{i}" for i in range(nodes)]
        self._ns_veths = [f"lc{tag}n{i}" for i in range(nodes)]
        self._made_bridge = False
        self._made_ns: list[str] = []
        self._made_veths: list[str] = []

    def setup(self) -> NetnsNetwork:
        try:
            _ip("link", "add", self.bridge, "type", "bridge")
            self._made_bridge = True
            _ip("addr", "add", f"{self.host_address}/{self.prefixlen}", "dev", self.bridge)
            _ip("link", "set", self.bridge, "up")
            for ns, host_veth, ns_veth, addr in zip(self.namespaces, self.host_veths,
                                                    self._ns_veths, self.node_addresses,
                                                    strict=True):
                _ip("netns", "add", ns)
                self._made_ns.append(ns)
                _ip("link", "add", host_veth, "type", "veth", "peer", "name", ns_veth)
                self._made_veths.append(host_veth)
                _ip("link", "set", ns_veth, "netns", ns)
                _ip("link", "set", host_veth, "master", self.bridge)
                _ip("link", "set", host_veth, "up")
                _ip("-n", ns, "addr", "add", f"{addr}/{self.prefixlen}", "dev", ns_veth)
                _ip("-n", ns, "link", "set", ns_veth, "up")
                _ip("-n", ns, "link", "set", "lo", "up")
        except BaseException:
            self.teardown()
            raise
        return self

    def teardown(self) -> None:
        """Remove the namespaces, then the host ends of the veths (gone with their namespace
        unless a process still holds it), then the bridge. Stop the processes inside first."""
        errors = []
        for ns in reversed(self._made_ns):
            with contextlib.suppress(subprocess.CalledProcessError):
                _ip("netns", "del", ns)
        self._made_ns.clear()
        for veth in reversed(self._made_veths):
            try:
                _ip("link", "del", veth)
            except subprocess.CalledProcessError as e:
                # Usually already gone with its namespace's end of the pair.
                if Path("/sys/class/net", veth).exists():
                    errors.append(e.stderr.strip())
        self._made_veths.clear()
        if self._made_bridge:
            try:
                _ip("link", "del", self.bridge)
            except subprocess.CalledProcessError as e:
                errors.append(e.stderr.strip())
            self._made_bridge = False
        if errors:
            print("netns teardown:", "; ".join(errors), file=sys.stderr)

    def exec_prefix(self, node: int) -> list[str]:
        return ["ip", "netns", "exec", self.namespaces[node]]

    def veth_bytes(self) -> int:
        """Bytes sent plus received so far on the host ends of the veths."""
        total = 0
        for veth in self.host_veths:
            stats = Path("/sys/class/net", veth, "statistics")
            total += int((stats / "rx_bytes").read_text()) + int((stats / "tx_bytes").read_text())
        return total

    def __enter__(self) -> NetnsNetwork:
        return self.setup()

    def __exit__(self, *exc: object) -> None:
        self.teardown()


def node_sizes(processes: int, per_node: int) -> list[int]:
    """Pool processes of each worker node: ``per_node`` each, the remainder on the last."""
    sizes = [per_node] * (processes // per_node)
    if processes % per_node:
        sizes.append(processes % per_node)
    return sizes


def start_nodes(redis_url: str, sizes: list[int], network: NetnsNetwork | None
                ) -> list[subprocess.Popen]:
    """One ``celery worker`` node per entry of ``sizes``, in its namespace when ``network``."""
    procs = []
    for i, concurrency in enumerate(sizes):
        prefix = network.exec_prefix(i) if network else []
        # ``ip netns exec`` execs the command in place, so the parent-death signal still holds.
        procs.append(subprocess.Popen(
            prefix + worker_command(concurrency, name=f"scaling{i}@%h"), cwd=ROOT,
            env=worker_env(redis_url, 1, {"LUCENT_KEY_PREFIX": KEY_PREFIX}),
            preexec_fn=_die_with_parent, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    return procs


def stop_nodes(procs: list[subprocess.Popen], grace: float = 30.0) -> None:
    """SIGTERM every node at once (Celery's warm shutdown), SIGKILL what is left after
    ``grace`` seconds."""
    for p in procs:
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + grace
    for p in procs:
        try:
            p.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def client_addresses(r: redis.Redis) -> set[str]:
    """The source addresses of Redis' connected clients."""
    return {c["addr"].rsplit(":", 1)[0] for c in r.client_list()}


def pass_label(first: int, largest: int) -> str:
    """``8 spp`` (equal passes) or ``8-64 spp`` (passes growing from 8 to at most 64)."""
    return f"{first} spp" if largest <= first else f"{first}-{largest} spp"


def measure_farm(processes: int, shapes: list[tuple[int, int, int]], scene: dict, repeats: int,
                 per_node: int, netns: bool, subnet: str) -> list[dict]:
    """Start a farm of ``processes`` worker processes and time every (tile, pass) shape on it."""
    sizes = node_sizes(processes, per_node)
    rows = []
    with contextlib.ExitStack() as stack:
        network = stack.enter_context(NetnsNetwork(len(sizes), subnet)) if netns else None
        server = EmbeddedRedis(host=network.host_address if network else "127.0.0.1").start()
        stack.callback(server.stop)
        procs = start_nodes(server.url, sizes, network)
        stack.callback(stop_nodes, procs)
        store = JobStore(redis.Redis.from_url(server.url), KEY_PREFIX)
        stack.callback(store.r.close)

        def ready() -> bool:
            if any(p.poll() is not None for p in procs):
                raise RuntimeError("a worker node exited during start-up")
            return sum(w.get("state") == "idle" for w in store.workers()) >= processes

        _wait(ready, timeout=300, interval=0.2)
        if network:
            # Every node must reach Redis from its own namespace address, through its veth.
            seen = client_addresses(store.r) & set(network.node_addresses)
            if len(seen) != len(sizes):
                raise RuntimeError(f"Redis sees {len(seen)} namespace addresses, not {len(sizes)}")
        settings = Settings(redis_url=server.url, key_prefix=KEY_PREFIX)
        with TestClient(create_app(settings)) as client:
            # Untimed: loads the kernels and compiles a scene in every process.
            run_job(client, {"scene": scene, "tile_size": shapes[0][0],
                             "spp_per_pass": shapes[0][1], "max_spp_per_pass": shapes[0][2]})
            for tile, per_pass, largest in shapes:
                body = {"scene": scene, "tile_size": tile, "spp_per_pass": per_pass,
                        "max_spp_per_pass": largest}
                veth_before = network.veth_bytes() if network else 0
                # Alternated with the local render on as many threads, so that both see the
                # same drift of the machine
                runs, local = [], []
                for _ in range(repeats):
                    local.append(local_seconds(scene, processes))
                    runs += timed_runs(client, store, body, 1, processes)
                veth_mb = (network.veth_bytes() - veth_before) / 1e6 / repeats if network else None
                med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
                row = {"mode": "netns" if network else "loopback", "workers": processes,
                       "nodes": len(sizes), "tile": tile, "spp_per_pass": per_pass,
                       "max_spp_per_pass": largest, "pass_growth": settings.pass_growth,
                       "tasks": int(med["tasks"]), "done_s": med["done"],
                       "preview_s": med["preview"], "samples_per_s": med["samples"] / med["done"],
                       "local_s": statistics.median(local),
                       "of_local": statistics.median(local) / med["done"],
                       "overhead_ms": med["overhead_ms"],
                       "wall_overhead_ms": med["wall_overhead_ms"],
                       "rendering": med["rendering"], "veth_mb_per_job": veth_mb}
                rows.append(row)
                print(f"  {processes:>3} workers ({len(sizes)} nodes), tile {tile:>3} px / "
                      f"{pass_label(per_pass, largest):>10}: done {row['done_s']:.2f} s, "
                      f"{row['samples_per_s'] / 1e6:.2f} M samples/s "
                      f"({100 * row['of_local']:.0f} % of local: {row['local_s']:.2f} s), "
                      f"{row['tasks']} tasks, "
                      f"overhead {row['overhead_ms']:.1f} / {row['wall_overhead_ms']:.1f} ms"
                      + (f", {veth_mb:.1f} MB over the veths" if network else ""), flush=True)
    return rows


def _shape(row: dict) -> tuple[int, int, int]:
    return row["tile"], row["spp_per_pass"], row.get("max_spp_per_pass", row["spp_per_pass"])


def add_speedups(rows: list[dict]) -> None:
    """Speedup against the smallest worker count of the same shape; efficiency per process."""
    for row in rows:
        same = [r for r in rows if _shape(r) == _shape(row)]
        base = min(same, key=lambda r: r["workers"])
        row["speedup"] = base["done_s"] / row["done_s"]
        row["efficiency"] = row["speedup"] * base["workers"] / row["workers"]


def markdown_table(rows: list[dict]) -> str:
    netns = any(r["veth_mb_per_job"] is not None for r in rows)
    head = ["workers (nodes)", "tile / pass", "tasks", "done", "samples/s", "local render",
            "of local", "speedup", "efficiency", "in-task overhead", "wall-clock overhead"] \
        + (["veth MB/job"] * netns)
    lines = ["| " + " | ".join(head) + " |",
             "|---|---|" + "---:|" * (len(head) - 2)]
    for r in sorted(rows, key=lambda r: (*_shape(r), r["workers"])):
        cells = [f"{r['workers']} ({r['nodes']})",
                 f"{r['tile']} px / {pass_label(*_shape(r)[1:])}",
                 str(r["tasks"]), f"{r['done_s']:.2f} s", f"{r['samples_per_s'] / 1e6:.2f} M",
                 f"{r['local_s']:.2f} s", f"{100 * r['of_local']:.0f} %",
                 f"{r['speedup']:.2f}×", f"{100 * r['efficiency']:.0f} %",
                 f"{r['overhead_ms']:.1f} ms", f"{r['wall_overhead_ms']:.1f} ms"]
        if netns:
            cells.append(f"{r['veth_mb_per_job']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return (f"{os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")


def _ints(text: str) -> list[int]:
    values = [int(v) for v in text.split(",") if v.strip()]
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def _passes(text: str) -> list[tuple[int, int]]:
    """``8,16,8-64`` -> [(8, 8), (16, 16), (8, 64)]: (first pass, largest pass)."""
    out = []
    for item in (v.strip() for v in text.split(",") if v.strip()):
        first, _, largest = item.partition("-")
        try:
            pair = (int(first), int(largest or first))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected N or N-M, got {item!r}") from None
        if min(pair) < 1 or pair[1] < pair[0]:
            raise argparse.ArgumentTypeError(f"expected 1 <= N <= M, got {item!r}")
        out.append(pair)
    if not out:
        raise argparse.ArgumentTypeError(f"expected N or N-M, got {text!r}")
    return out


def _raise_exit(signum: int, _frame: object) -> None:
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="examples/cornell_box.json")
    parser.add_argument("--spp", type=int, help="render.spp instead of the scene's")
    parser.add_argument("--workers", type=_ints, default=[1, 2],
                        help="worker process counts, e.g. 1,2,4,8,16 (default 1,2)")
    parser.add_argument("--tiles", type=_ints, default=[32, 64], help="tile sizes in pixels")
    parser.add_argument("--passes", type=_passes, default=[(8, 8), (16, 16), (8, 64)],
                        help="samples per pass: N (equal passes) or N-M (growing from N to at "
                             "most M, services.farm.planner), comma-separated (default 8,16,8-64)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per row (median)")
    parser.add_argument("--per-node", type=int, default=1,
                        help="pool processes per worker node (and per namespace with --netns)")
    parser.add_argument("--netns", action="store_true",
                        help="every worker node in its own network namespace (root, iproute2)")
    parser.add_argument("--subnet", default="10.213.0.0/24", help="addresses for --netns")
    parser.add_argument("--csv", type=Path, help="also write the rows to this CSV file")
    args = parser.parse_args(argv)

    # SIGTERM unwinds like Ctrl-C, so that workers, Redis and namespaces are cleaned up.
    signal.signal(signal.SIGTERM, _raise_exit)
    scene = json.loads(Path(args.scene).read_text())
    if args.spp:
        scene["render"]["spp"] = args.spp
    shapes = [(t, p, m) for t in args.tiles for p, m in args.passes]
    mode = (f"netns: every worker node in its own network namespace ({args.subnet})"
            if args.netns else "loopback: workers and Redis on 127.0.0.1")
    print(f"{args.scene}: {scene['film']['width']}x{scene['film']['height']}, "
          f"{scene['render']['spp']} spp; {machine()}\n{mode}; {args.per_node} process(es) per "
          f"node, 1 numba thread each; medians of {args.repeats} runs", flush=True)
    if max(args.workers) > (os.cpu_count() or 1):
        print(f"note: {max(args.workers)} workers on {os.cpu_count()} cores", flush=True)

    rows = []
    for processes in args.workers:
        rows += measure_farm(processes, shapes, scene, args.repeats, args.per_node, args.netns,
                             args.subnet)
    add_speedups(rows)
    print()
    print(markdown_table(rows))
    if args.csv:
        with args.csv.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
