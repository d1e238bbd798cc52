"""How the kernels are compiled: the serial kernels run without numba's runtime (NRT), safely."""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest
from numba.core.registry import CPUDispatcher

import renderer
from tests.conftest import EARLY, Early

ROOT = Path(__file__).resolve().parents[2]
# The kernels that need the runtime: those that allocate arrays (alloc_kernel) and the parallel
# ones (parallel_kernel).
WITH_RUNTIME = {
    "renderer.geometry.bvh.build_bvh",
    "renderer.geometry.bvh.widen_bvh",
    "renderer.geometry.bvh.traversal_stack",
    "renderer.geometry.shapes.prim_bounds",
    # the wavefront kernel's stages on the CPU: parallel loops (numba's thread pool runs on it)
    *(f"renderer.wavefront.stages.{stage}"
      for stage in ("generate", "trace_rays", "shade", "accumulate")),
}


def _dispatchers() -> dict[str, CPUDispatcher]:
    out = {}
    for info in pkgutil.walk_packages(renderer.__path__, "renderer."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == module.__name__:
                out[f"{module.__name__}.{name}"] = obj
    return out


def test_serial_kernels_run_without_the_runtime():
    kernels = _dispatchers()
    assert len(kernels) > 50
    assert WITH_RUNTIME <= kernels.keys()
    for name, dispatcher in kernels.items():
        uses_runtime = dispatcher.targetoptions.get("_nrt", True)
        assert uses_runtime == (name in WITH_RUNTIME), name


AUDIT = r"""
import json, sys
import numba
from renderer.render import render_tile
from renderer.scene.compile import compile_scene
from renderer.scene.load import load_scene_file
sys.path.insert(0, sys.argv[1])
import test_jit

for path in json.loads(sys.argv[2]):
    render_tile(compile_scene(load_scene_file(path)), 0, 0, 4, 4, 0, 1)

def holds_array(t):
    if isinstance(t, numba.types.Array):
        return True
    return isinstance(t, numba.types.BaseTuple) and any(holds_array(x) for x in t)

report = {"signatures": 0, "bad": []}
for name, d in test_jit._dispatchers().items():
    for sig in d.nopython_signatures:
        report["signatures"] += 1
        if not d.targetoptions.get("_nrt", True) and holds_array(sig.return_type):
            report["bad"].append(f"{name} -> {sig.return_type}")
print(json.dumps(report))
"""


# Compiled from an empty cache: a process of its own, started with the session (tests.conftest.
# Early) beside the suite's own compile
_AUDIT = Early(
    [sys.executable, "-c", AUDIT, str(Path(__file__).parent),
     json.dumps(sorted(str(p) for p in (ROOT / "examples").glob("*.json")))],
    {**os.environ, "NUMBA_CACHE_DIR": "{folder}"}, str(ROOT))
EARLY["tests/renderer/test_jit.py::test_no_runtime_free_kernel_returns_an_array"] = _AUDIT


@pytest.mark.slow
def test_no_runtime_free_kernel_returns_an_array():
    """Compiled from an empty cache (so every device function is compiled and typed in this
    process, not loaded), no kernel without the runtime returns an array or a tuple holding one:
    the NRT-enabled caller would release a reference the callee never took."""
    out = _AUDIT.result(timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["signatures"] > 50  # the device functions were compiled here, not loaded
    assert report["bad"] == []


def test_kernels_cache_in_the_keyed_folder_when_numba_was_imported_first(tmp_path):
    """A program that imports numba before the renderer (bench.where_time_goes did) must still
    cache the renderer's kernels under LUCENT_CACHE_DIR, not in __pycache__ beside the sources."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["LUCENT_CACHE_DIR"] = str(tmp_path)
    code = ("import numba\n"
            "import renderer, os\n"
            "from renderer.rng import mix64\n"
            "print(mix64._cache._cache_path)\n"
            "print(os.environ['NUMBA_CACHE_DIR'])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=tmp_path, check=True).stdout.split()
    assert out[1].startswith(str(tmp_path))
    assert out[0].startswith(out[1]), out


INLINING = r"""
import json, math, re
from renderer.jit import inline_kernel, kernel


@kernel
def stays_a_call(x, n):
    s = 0.0
    for i in range(n):
        s += math.sin(x * i)
    return s


@inline_kernel
def folded(x, k, flag):
    if flag:
        return x * k + stays_a_call(x, 3)
    return x - k


@kernel
def caller(x):
    return folded(x, 2, True) + folded(x, 3, False)


def attributes(dispatcher, name):
    (ir,) = dispatcher.inspect_llvm().values()
    group = re.search(r"define [^\n]*" + name + r"[^\n]*\) (?:local_unnamed_addr )?#(\d+)", ir)
    return re.search(r"attributes #" + group.group(1) + r" = \{([^}]*)\}", ir).group(1).split()


value = caller(1.5)
(caller_ir,) = caller.inspect_llvm().values()
print(json.dumps({
    "value": value, "expected": 1.5 * 2 + sum(math.sin(1.5 * i) for i in range(3)) + 1.5 - 3,
    "folded_signatures": [str(s) for s in folded.signatures],
    "folded": attributes(folded, "folded"),
    "stays_a_call": attributes(stays_a_call, "stays_a_call"),
    "calls_left": sorted(set(re.findall(r"call [^\n]*@(\S*(?:folded|stays_a_call)\S*)\(",
                                        caller_ir))),
}))
"""


def test_inline_kernels_are_typed_once_and_inlined_by_llvm(tmp_path):
    """An inline_kernel is compiled once for the plain types of its arguments, whatever constants
    its callers pass (numba would compile one per literal), and marked alwaysinline for LLVM; a
    kernel first compiled while an inline_kernel is typed does not inherit the mark. Compiled in
    a fresh process and cache, so the functions are compiled and their IR is there to read."""
    (tmp_path / "inlining_probe.py").write_text(INLINING)
    env = {**os.environ, "LUCENT_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, str(tmp_path / "inlining_probe.py")], cwd=ROOT,
                         env={**env, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                         timeout=300, check=True)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["value"] == pytest.approx(report["expected"], rel=1e-12)
    assert report["folded_signatures"] == ["(float64, int64, bool)"]
    assert "alwaysinline" in report["folded"]
    assert "alwaysinline" not in report["stays_a_call"]
    assert not any("folded" in name for name in report["calls_left"])


def test_claim_row_hands_every_row_out_once():
    """``claim_row``, the rows' counter that a pass's threads share: two threads claiming as fast
    as they can, 10⁶ claims in all, each in a compiled loop and each index claimed once (an add
    that is not atomic, a read and a write, hands some out twice and skips none); as Python
    (``NUMBA_DISABLE_JIT``'s path, under a lock) the same, and a claim past the end is past it."""
    import numpy as np

    from renderer.jit import claim_row, kernel, run_chunks

    @kernel
    def claim_all(counter, n, out):
        got = 0
        while True:
            row = claim_row(counter)
            if row >= n:
                return got
            out[row] += 1
            got += 1

    n = 1_000_000
    counter = np.zeros(1, np.int64)
    out = np.zeros(n, np.int64)
    got = [0, 0]

    def chunk(c: int) -> None:
        got[c] = claim_all(counter, n, out)

    run_chunks(chunk, 2)
    assert sum(got) == n and (out == 1).all()
    assert counter[0] == n + 2  # (each thread's last claim, past the end)
    counter[0] = 5
    assert [claim_row(counter) for _ in range(3)] == [5, 6, 7] and counter[0] == 8
