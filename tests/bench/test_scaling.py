"""bench/scaling.py: the network-namespace helper (a client in a namespace reaches Redis only
through its veth; setup and teardown leave nothing behind, even when setup fails half-way) and
the speedup arithmetic. The benchmark's timings themselves are recorded in docs/performance.md."""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys

import pytest
import redis

from bench.scaling import NetnsNetwork, _passes, add_speedups, node_sizes, pass_label
from services.launcher import EmbeddedRedis


def _netns_usable() -> bool:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        return False
    name = f"lucent-probe-{os.getpid()}"
    if subprocess.run(["ip", "netns", "add", name], capture_output=True).returncode != 0:
        return False
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return True


netns = pytest.mark.skipif(not _netns_usable(), reason="needs root and `ip netns`")


def _leftovers(net: NetnsNetwork) -> list[str]:
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    names = [ns for ns in net.namespaces if ns in listed.split()]
    links = [net.bridge, *net.host_veths]
    return names + [link for link in links if os.path.exists(f"/sys/class/net/{link}")]


def _in_namespace(net: NetnsNetwork, node: int, code: str) -> subprocess.CompletedProcess:
    return subprocess.run(net.exec_prefix(node) + [sys.executable, "-c", code],
                          capture_output=True, text=True, timeout=60)


@pytest.mark.slow
@netns
def test_namespace_reaches_redis_only_through_its_veth():
    net = NetnsNetwork(2, subnet="10.214.7.0/29", tag=f"t{os.getpid() % 10_000}")
    server = None
    try:
        net.setup()
        server = EmbeddedRedis(host=net.host_address).start()
        before = net.veth_bytes()
        payload = 200_000
        write = (f"import redis; r = redis.Redis(host={net.host_address!r}, port={server.port});"
                 f"r.set('from-ns', b'x' * {payload});"
                 "print(r.client_list()[-1]['addr'])")
        done = _in_namespace(net, 1, write)
        assert done.returncode == 0, done.stderr
        # Redis saw the namespace's own address, and the bytes crossed the veths.
        assert done.stdout.strip().rsplit(":", 1)[0] == net.node_addresses[1]
        assert len(redis.Redis.from_url(server.url).get("from-ns")) == payload
        assert net.veth_bytes() - before > payload
        # The host's loopback is not the namespace's: 127.0.0.1 there has no Redis.
        local = _in_namespace(net, 0, f"import redis; redis.Redis(port={server.port}).ping()")
        assert local.returncode != 0 and "ConnectionError" in local.stderr
    finally:
        if server is not None:
            server.stop()
        net.teardown()
    assert _leftovers(net) == []


@pytest.mark.slow
@netns
def test_failed_setup_removes_what_it_made_and_only_that():
    net = NetnsNetwork(3, subnet="10.214.7.8/29", tag=f"f{os.getpid() % 10_000}")
    # A namespace of the same name already exists: setup fails at node 1.
    subprocess.run(["ip", "netns", "add", net.namespaces[1]], check=True)
    try:
        with pytest.raises(subprocess.CalledProcessError):
            net.setup()
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert net.namespaces[1] in listed.split()  # not ours: left alone
        subprocess.run(["ip", "netns", "del", net.namespaces[1]], check=True)
        assert _leftovers(net) == []
    finally:
        subprocess.run(["ip", "netns", "del", net.namespaces[1]], capture_output=True)


def test_node_sizes_cover_every_process():
    assert node_sizes(5, 2) == [2, 2, 1]
    assert node_sizes(16, 1) == [1] * 16
    assert node_sizes(8, 4) == [4, 4]


def test_speedup_is_against_the_smallest_count_of_the_same_shape():
    rows = [{"tile": 32, "spp_per_pass": 8, "workers": w, "done_s": t}
            for w, t in [(2, 10.0), (4, 6.0), (8, 5.0)]]
    rows.append({"tile": 64, "spp_per_pass": 8, "workers": 4, "done_s": 3.0})
    add_speedups(rows)
    assert [round(r["speedup"], 6) for r in rows] == [1.0, round(10 / 6, 6), 2.0, 1.0]
    assert rows[1]["efficiency"] == pytest.approx(10 / 6 * 2 / 4)
    assert rows[2]["efficiency"] == pytest.approx(0.5)
    assert rows[3]["efficiency"] == 1.0


def test_pass_shapes_parse_equal_and_growing_passes():
    assert _passes("8,16,8-64") == [(8, 8), (16, 16), (8, 64)]
    assert [pass_label(*p) for p in _passes("8, 8-64")] == ["8 spp", "8-64 spp"]
    assert _passes("8-") == [(8, 8)]  # no largest given: equal passes
    for bad in ("", "0", "16-8", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            _passes(bad)


def test_growing_passes_are_a_shape_of_their_own():
    rows = [{"tile": 32, "spp_per_pass": 8, "max_spp_per_pass": m, "workers": w, "done_s": t}
            for m, w, t in [(8, 1, 10.0), (8, 2, 5.0), (64, 1, 6.0), (64, 2, 4.0)]]
    add_speedups(rows)
    assert [r["speedup"] for r in rows] == [1.0, 2.0, 1.0, 1.5]
