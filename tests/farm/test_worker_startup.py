"""A worker node's start-up with a cold kernel cache (worker.runtime.prewarm_cache).

The node's main process fills a cold cache once, in a child, before the prefork pool forks, and
the pool processes only load the kernels: one compile a node instead of one a pool process, and a
pool process started in place of one that died never compiles under Celery's
``worker_proc_alive_timeout``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import redis

from services.farm.store import JobStore
from services.launcher import worker_command, worker_env
from tests.conftest import COUNTED_PATH_KERNEL, EARLY, Early, wait_until
from worker import runtime

ROOT = Path(__file__).resolve().parents[2]


def test_prewarm_fills_a_cold_cache_once_and_then_costs_nothing():
    # The suite's cache holds the kernels, so the child only loads them and leaves the marker;
    # with the marker there, nothing runs at all
    marker = runtime.warm_marker()
    marker.unlink(missing_ok=True)
    seconds = runtime.prewarm_cache()
    assert seconds is not None and seconds > 0.0
    assert marker.exists()
    assert runtime.prewarm_cache() is None


def test_a_packet_nodes_prewarm_marks_the_cache_only_when_both_children_succeed(monkeypatch,
                                                                                tmp_path):
    """A packet node compiles its two kernels in two children at once; the cache is marked warm
    only once both are done: a child that fails (here the packet one) leaves it unmarked, and
    the pool processes compile as before."""
    marker = runtime.warm_marker()
    was_warm = marker.exists()
    marker.unlink(missing_ok=True)
    ran = tmp_path / "children"  # what each child was asked to warm up
    try:
        monkeypatch.setattr(runtime, "_WARM_UP", (
            "import sys; p, k, w = sys.argv[-3:]; open(p, 'a').write(k + ' ' + w + '\\n'); "
            "sys.exit(k == 'packet')"))
        real_popen = subprocess.Popen
        monkeypatch.setattr(runtime.subprocess, "Popen",
                            lambda args, **kw: real_popen([*args[:3], str(ran), *args[3:]], **kw))
        assert runtime.prewarm_cache("packet") is None
        assert not marker.exists()
        assert sorted(ran.read_text().split("\n")[:-1]) == ["packet alone", "scalar scalar"]
        ran.unlink()
        assert runtime.prewarm_cache("scalar") is not None  # one child, which succeeds
        assert marker.exists() and ran.read_text() == "scalar scalar\n"
    finally:
        if not was_warm:
            marker.unlink(missing_ok=True)  # the marker as it was


def test_the_warm_up_loads_the_adaptive_rules_kernels():
    """A worker's warm-up also loads (or compiles) the kernels of render.target_error's rule, so
    a pool process's first pass of a job with a target does not pay for them. In a fresh
    process: after warm_up_kernels the two that a worker calls (through pass_counts and
    tile_summary) have a signature, compiled or loaded from the cache. (The window sums and the
    allocation's error they call are linked into them, so a load from the cache leaves those
    dispatchers empty.)"""
    code = ("from worker import runtime; runtime.warm_up_kernels(); "
            "from renderer.film import adaptive as a; "
            "print(all(k.signatures for k in (a._neighbour_variance_kernel, "
            "a._solve_scale)))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "True", out.stdout


def test_the_warm_up_loads_the_nodes_kernel():
    """A node with ``worker_kernel`` wavefront (or gpu) warms that kernel up too, beside the
    scalar one, so its first pass does not compile it. In a fresh process, after the warm-up of
    a WorkerState so configured, the wavefront kernel's trace stage (``trace_rays``, which the
    host calls) has a signature."""
    code = ("from worker import runtime; s = runtime.WorkerState(); s.warm_up(); "
            "from renderer.wavefront import stages; "
            "print(bool(stages.trace_rays.signatures))")
    env = dict(os.environ, LUCENT_WORKER_KERNEL="wavefront")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "True", out.stdout


GPU_WARM_UP = COUNTED_PATH_KERNEL + """
from worker import runtime
runtime.WorkerState().warm_up()
print(len(launches))
"""


@pytest.mark.slow
def test_a_gpu_nodes_warm_up_compiles_the_path_kernel_too():
    """A GPU node renders the scenes the stages do not cover (translucent ones) with the path
    kernel: its warm-up launches that too, so a first translucent pass does not compile it. On
    numba's CUDA simulator, with the shared functions as Python."""
    env = dict(os.environ, LUCENT_WORKER_KERNEL="gpu", NUMBA_ENABLE_CUDASIM="1",
               NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, "-W", "ignore", "-c", GPU_WARM_UP], cwd=ROOT,
                         capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "1", out.stdout


# A node on an empty kernel cache, started with the session (tests.conftest.Early) on a Redis of
# its own, so that its compile runs beside the suite's
_COLD_NODE = Early(
    worker_command(2, "startup-cold@%h", loglevel="INFO"),
    worker_env("{redis}", 1, {"LUCENT_KEY_PREFIX": "startup-cold",
                              "LUCENT_HEARTBEAT_INTERVAL": "0.5", "LUCENT_API_TOKEN": "",
                              "NUMBA_CACHE_DIR": "{folder}/numba"}),
    str(ROOT), redis=True)
EARLY["tests/farm/test_worker_startup.py::"
      "test_a_cold_node_compiles_once_and_its_pool_processes_only_load"] = _COLD_NODE


@pytest.mark.slow
def test_a_cold_node_compiles_once_and_its_pool_processes_only_load():
    # An empty kernel cache: the node's main process compiles (in a child) before the pool
    # forks, and both pool processes then come up warm in the time a load takes, far less than
    # the compile (without the prewarm, each would compile: "warm in" ~ the compile)
    proc = _COLD_NODE.running()
    store = JobStore(redis.Redis.from_url(_COLD_NODE.redis_url), "startup-cold")
    try:
        wait_until(lambda: sum(w.get("state") == "idle" for w in store.workers()) >= 2
                   or proc.poll() is not None, 600.0, "two warm pool processes", interval=0.5)
        text = _COLD_NODE.output()
        assert proc.poll() is None, text[-3000:]
        compiled = re.findall(r"kernel cache was cold: compiled in ([0-9.]+) s", text)
        warm = [float(x) for x in re.findall(r"warm in ([0-9.]+) s", text)]
        assert len(compiled) == 1 and len(warm) == 2, text[-3000:]
        assert max(warm) < 0.25 * float(compiled[0]), (warm, compiled)
        assert _COLD_NODE.folder is not None
        assert runtime.warm_marker().name in os.listdir(_COLD_NODE.folder / "numba")
    finally:
        store.r.close()
        _COLD_NODE.stop()
