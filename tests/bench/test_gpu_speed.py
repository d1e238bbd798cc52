"""bench.gpu_speed runs only where a GPU is lent, rarely and for minutes: it must work the first
time there. Here it runs end to end on numba's CUDA simulator, on a 4×3 frame."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_the_gpu_benchmark_runs_end_to_end_on_the_simulator(tmp_path):
    """Every part of the run (the batch and tail sweeps and their grid, an empty launch, the
    path kernel, the farm pass, the CPU kernels, the pixel-by-pixel comparisons) completes and is
    written to the JSON, for a scene the stages cover and a translucent one they do not; the
    simulated kernels give the CPU kernels' buffers, so the comparisons say equal.
    Mitsuba's CUDA variant cannot load here: it is reported as unavailable, not an error."""
    out = tmp_path / "gpu.json"
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", NUMBA_DISABLE_JIT="1",
               PYTHONPATH=str(ROOT))
    run = subprocess.run(
        [sys.executable, "-W", "ignore", "-m", "bench.gpu_speed", "--scenes", "cornell_box",
         "translucent_sphere", "--film", "4x3", "--spp", "2", "--repeats", "1", "--batches",
         "3", "4", "--tails", "0", "1", "--grid", "--tile", "2", "--tile-spp", "1",
         "--variants", "cuda_ad_rgb", "--json", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    scenes = json.loads(out.read_text())["scenes"]
    row = scenes["cornell_box"]
    assert row["size"] == [4, 3] and row["gpu"]["kernel"] == "stages"
    assert set(row["gpu"]["by_batch"]) == {"3", "4"} and set(row["gpu"]["by_tail"]) == {"0.0",
                                                                                       "1.0"}
    assert set(row["gpu"]["by_pair"]) == {"2^3 0", "2^3 1", "2^4 0", "2^4 1"}
    assert row["gpu"]["launch_seconds"] > 0 and row["gpu"]["megakernel"]["seconds"] > 0
    assert row["gpu"]["tile"]["size"] == [2, 2]
    equal = {"same_counts": True, "pixels_equal_1e-6": 1.0, "mean_relative_difference": 0.0}
    assert row["gpu stages vs cpu wavefront"] == equal
    assert row["gpu path_kernel vs cpu scalar"] == equal
    assert row["cpu scalar"]["paths_per_second"] > 0
    assert row["cpu wavefront"]["paths_per_second"] > 0
    assert "unavailable" in row["mitsuba cuda_ad_rgb"]
    # A translucent scene: path_kernel only, against the scalar kernel
    row = scenes["translucent_sphere"]
    assert row["gpu"]["kernel"] == "path_kernel" and set(row["gpu"]["by_batch"]) == {"3", "4"}
    assert row["gpu"]["by_tail"] == {} and row["gpu"]["by_pair"] == {}
    assert row["gpu path_kernel vs cpu scalar"] == equal
    assert "cpu wavefront" not in row and "gpu stages vs cpu wavefront" not in row
