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

ROOT = Path(__file__).resolve().parents[2]
# The kernels that allocate arrays, so need the runtime (alloc_kernel, parallel_kernel).
WITH_RUNTIME = {
    "renderer.geometry.bvh.build_bvh",
    "renderer.geometry.bvh.widen_bvh",
    "renderer.geometry.bvh.traversal_stack",
    "renderer.geometry.shapes.prim_bounds",
    "renderer.integrators.path.render_tile_kernel",
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


@pytest.mark.slow
def test_no_runtime_free_kernel_returns_an_array(tmp_path):
    """Compiled from an empty cache (so every device function is compiled and typed in this
    process, not loaded), no kernel without the runtime returns an array or a tuple holding one:
    the NRT-enabled caller would release a reference the callee never took."""
    examples = sorted(str(p) for p in (ROOT / "examples").glob("*.json"))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", AUDIT, str(Path(__file__).parent), json.dumps(examples)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600, check=True)
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
