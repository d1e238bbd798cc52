"""The wavefront stages as CUDA kernels, run on numba's CUDA simulator against the CPU kernel."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from renderer.render import render_tile
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from renderer.wavefront.cpu import render_tile_wavefront
from tests.conftest import COUNTED_PATH_KERNEL

ROOT = Path(__file__).resolve().parents[3]

# In a subprocess: the simulator must be chosen before numba.cuda is imported, and with
# NUMBA_DISABLE_JIT the per-path functions the kernels share with the CPU stages run as Python
# (the simulator passes its own array type, which compiled CPU functions do not take)
SIMULATED = r"""
import json, sys, warnings
import numpy as np
warnings.simplefilter("ignore")  # SplitMix64's uint64 products wrap, as intended, in NumPy too
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from renderer.render import render_tile
from renderer.wavefront.gpu import render_tile_gpu
out = {}
for name, data in json.loads(sys.argv[1]).items():
    cs = compile_scene(load_scene(data))
    active = np.ones((cs.height, cs.width), np.uint8)
    active[0, :3] = 0
    for tail in (0.0, 0.5, 1.0):
        b = render_tile_gpu(cs, 0, 0, cs.width, cs.height, 2, 6, active, batch_paths=60,
                            tail=tail)
        out[f"{name} {tail}"] = {"sum": b.sum.tolist(), "sum_sq": b.sum_sq.tolist(),
                                 "count": b.count.tolist()}
    # render_tile's gpu kernel, a pixel's samples given by counts (adaptive sampling)
    counts = np.full((cs.height, cs.width), 6, np.int32)
    counts[1:3, :] = 3
    counts[0, :3] = 0
    b = render_tile(cs, 0, 0, cs.width, cs.height, 2, 6, counts, kernel="gpu")
    out[f"{name} counts"] = {"sum": b.sum.tolist(), "sum_sq": b.sum_sq.tolist(),
                             "count": b.count.tolist()}
print(json.dumps(out))
"""


def scenes() -> dict:
    out = {}
    for name in ("cornell_box", "glass_sphere"):
        data = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        data["film"] = {"width": 8, "height": 6}
        out[name] = data
    return out


@pytest.mark.slow
def test_cuda_kernels_on_the_simulator_match_the_cpu_kernel():
    """An 8×6 Cornell box and glass sphere, 6 spp from sample 2, three pixels masked off, in
    batches of 10 pixels: the CUDA kernels (queues compacted with an atomic counter, so in a
    varying order) give the CPU wavefront kernel's sample buffers to rounding — the same paths,
    as they run the same per-path code; a stage that lost a path, or read another path's slot,
    would change whole pixels. So do they whether the batch's tail is finished one thread a
    path from the start (tail 1), from half the paths live (0.5) or never (0), and through
    ``render_tile(kernel="gpu")`` with a count a pixel."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", NUMBA_DISABLE_JIT="1", PYTHONPATH=str(ROOT))
    run = subprocess.run([sys.executable, "-c", SIMULATED, json.dumps(scenes())], env=env,
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    simulated = json.loads(run.stdout)
    for name, data in scenes().items():
        cs = compile_scene(load_scene(data))
        active = np.ones((cs.height, cs.width), np.uint8)
        active[0, :3] = 0
        cpu = render_tile_wavefront(cs, 0, 0, cs.width, cs.height, 2, 6, active)
        assert cpu.count.sum() == 6 * (8 * 6 - 3)
        assert cpu.sum.mean() > 0.1  # lit pixels, not a blank image matching a blank image
        counts = np.full((cs.height, cs.width), 6, np.int32)
        counts[1:3, :] = 3
        counts[0, :3] = 0
        cpu_counts = render_tile(cs, 0, 0, cs.width, cs.height, 2, 6, counts, kernel="wavefront")
        assert cpu_counts.count.sum() == 6 * (8 * 4 - 3) + 3 * 8 * 2
        for case, want in ((0.0, cpu), (0.5, cpu), (1.0, cpu), ("counts", cpu_counts)):
            gpu = simulated[f"{name} {case}"]
            np.testing.assert_array_equal(np.array(gpu["count"]), want.count)
            np.testing.assert_allclose(np.array(gpu["sum"]), want.sum, rtol=1e-12, atol=1e-300)
            np.testing.assert_allclose(np.array(gpu["sum_sq"]), want.sum_sq, rtol=1e-12,
                                       atol=1e-300)


# The path kernel: the scalar kernel's trace_path one CUDA thread a path, for the scenes the
# stages do not cover (and, asked, for one they do)
SIMULATED_PATHS = COUNTED_PATH_KERNEL + r"""
import json, sys, warnings
import numpy as np
warnings.simplefilter("ignore")
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from renderer.render import render_tile
from renderer.wavefront.gpu import render_tile_gpu
out = {}
for name, data in json.loads(sys.argv[1]).items():
    launches.clear()
    cs = compile_scene(load_scene(data))
    counts = np.full((cs.height, cs.width), 3, np.int32)
    counts[0, :3] = 0
    counts[2:4, :] = 1
    if name == "cornell_box":
        b = render_tile_gpu(cs, 0, 0, cs.width, cs.height, 1, 3, counts > 0, batch_paths=20,
                            megakernel=True)
        try:
            render_tile_gpu(cs, 0, 0, 2, 2, 0, 1, megakernel=False)
        except ValueError as err:
            out["refused"] = str(err)
    else:
        b = render_tile(cs, 0, 0, cs.width, cs.height, 1, 3, counts, kernel="gpu")
        try:
            render_tile_gpu(cs, 0, 0, 2, 2, 0, 1, megakernel=False)
        except ValueError as err:
            out[f"{name} refused"] = str(err)
    out[name] = {"sum": b.sum.tolist(), "sum_sq": b.sum_sq.tolist(), "count": b.count.tolist(),
                 "dropped": b.dropped.tolist(), "segments": b.segments.tolist(),
                 "launches": len(launches)}
print(json.dumps(out))
"""


def path_scenes() -> dict:
    out = {}
    for name, file, render in (("cornell_box", "cornell_box", {}),
                               ("cornell_sobol", "cornell_box", {"sampler": "sobol"}),
                               ("translucent_sphere", "translucent_sphere", {})):
        data = json.loads((ROOT / "examples" / f"{file}.json").read_text())
        data["film"] = {"width": 6, "height": 5}
        data["render"].update(render)
        out[name] = data
    return out


@pytest.mark.slow
def test_the_path_kernel_on_the_simulator_matches_the_scalar_kernel():
    """``path_kernel`` runs the scalar kernel's ``trace_path``, one thread a path: on the
    simulator it gives the scalar kernel's sample buffers to rounding, for a translucent sphere
    (volumetric random walks, which the stages do not cover) and the sobol sampler (its pixel's
    sequence seeds made in each thread), through ``render_tile(kernel="gpu")`` with a count a
    pixel (1, 3 and 0 samples from sample 1), and for the Cornell box when asked for, in several
    batches; each pixel's path segments (a sample's cost to adaptive sampling) as well. Asked
    not to use it, a scene the stages do not cover is refused, naming why."""
    scenes = path_scenes()
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", NUMBA_DISABLE_JIT="1", PYTHONPATH=str(ROOT))
    run = subprocess.run([sys.executable, "-c", SIMULATED_PATHS, json.dumps(scenes)], env=env,
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    simulated = json.loads(run.stdout)
    assert "refused" not in simulated  # the stages cover the Cornell box
    assert "material kinds translucent" in simulated["translucent_sphere refused"]
    assert simulated["cornell_sobol refused"].endswith("the sobol sampler")
    for name, data in scenes.items():
        cs = compile_scene(load_scene(data))
        counts = np.full((cs.height, cs.width), 3, np.int32)
        counts[0, :3] = 0
        counts[2:4, :] = 1
        want = render_tile(cs, 0, 0, cs.width, cs.height, 1, 3, counts, kernel="scalar")
        if name == "cornell_box":
            want = render_tile(cs, 0, 0, cs.width, cs.height, 1, 3, counts > 0, kernel="scalar")
        assert want.sum.mean() > 0.05  # lit pixels
        got = simulated[name]
        # by path_kernel: one launch a batch (the Cornell box's 27 pixels × 3 samples in batches
        # of 6 whole pixels); a tile of unequal counts (3, 1, 0) is one batch, not one a count
        assert got["launches"] == (5 if name == "cornell_box" else 1), got["launches"]
        np.testing.assert_array_equal(np.array(got["count"]), want.count)
        np.testing.assert_array_equal(np.array(got["dropped"]), want.dropped)
        # the paths' segments too, which adaptive sampling weighs as a sample's cost
        assert want.segments.sum() > want.count.sum()
        np.testing.assert_array_equal(np.array(got["segments"]), want.segments)
        np.testing.assert_allclose(np.array(got["sum"]), want.sum, rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(np.array(got["sum_sq"]), want.sum_sq, rtol=1e-12,
                                   atol=1e-300)
