"""Where a render's time goes: controlled experiments (numba code is opaque to Python profilers).

    .venv/bin/python -m bench.where_time_goes [--scene examples/cornell_box.json] [--spp 64]

Prints, for one scene at its resolution:
- the full render (``render_buffer``) on 2 threads and on 1: paths/s and the thread scaling;
- primary rays only: a kernel that makes the same camera rays (same keys and jitter) and finds
  their closest hit through the same BVH, nothing else — the cost floor of one coherent ray;
- per-row cost on 1 thread at 8 spp, and how evenly the frame's rows would split between 2 threads
  as 2 contiguous blocks (numba's static ``prange`` schedule) and interleaved (row k to thread
  k mod 2, what ``render_tile_kernel`` does). Efficiency = total / (2 × the busier thread's share).

docs/performance.md ("Where the time goes") records the results and the one-off experiments on
patched copies of the renderer (shadow rays off, rays counted per path).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numba
import numpy as np
from numba import prange

from renderer.geometry.bvh import intersect_closest, traversal_stack
from renderer.integrators.path import camera_ray
from renderer.jit import parallel_kernel
from renderer.render import render_buffer, render_tile
from renderer.rng import sample_key, uniform
from renderer.scene import load_scene_file
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[1]


@parallel_kernel
def primary_rays(S, width, height, seed, spp, stack_size, out):
    """Closest hits of every camera ray of ``spp`` samples per pixel; out[y] sums the t of hits."""
    for y in prange(height):
        stack = traversal_stack(stack_size)
        acc = 0.0
        for x in range(width):
            for s in range(spp):
                key = sample_key(seed, y * width + x, s)
                o, d = camera_ray(S.camera, width, height, x, y, uniform(key, 0), uniform(key, 1))
                t, prim, _, _ = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count,
                                                  S.flat, S.prim_kind, S.prim_geo, o, d, math.inf,
                                                  stack)
                acc += t if prim >= 0 else 0.0
        out[y] = acc


def best_of(fn, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default=str(ROOT / "examples" / "cornell_box.json"))
    parser.add_argument("--spp", type=int, default=64)
    args = parser.parse_args()
    cs = compile_scene(load_scene_file(args.scene))
    w, h, spp = cs.width, cs.height, args.spp
    out = np.zeros(h)
    primary_rays(cs.arrays, w, h, cs.seed, 1, cs.stack_size, out)  # compile / load
    render_buffer(cs, 1)
    print(f"{Path(args.scene).name}: {w}x{h}, {spp} spp, {len(cs.arrays.prim_kind)} primitives, "
          f"{cs.info['bvh_nodes']} BVH nodes; threading layer {numba.threading_layer()}")
    paths = w * h * spp
    full = {}
    for threads in (2, 1):
        numba.set_num_threads(threads)
        full[threads] = best_of(lambda: render_buffer(cs, spp), 2)
        prim = best_of(lambda: primary_rays(cs.arrays, w, h, cs.seed, spp, cs.stack_size, out), 2)
        print(f"{threads} thread(s): full render {full[threads]:.3f} s = "
              f"{paths / full[threads] / 1e6:.3f} M paths/s; primary rays only {prim:.3f} s = "
              f"{paths / prim / 1e6:.2f} M rays/s")
    print(f"thread scaling 1 -> 2: {full[1] / full[2]:.2f}x")

    numba.set_num_threads(1)
    row = np.zeros(h)
    for y in range(h):
        start = time.perf_counter()
        render_tile(cs, 0, y, w, 1, 0, 8)
        row[y] = time.perf_counter() - start
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    total = row.sum()
    blocks = max(row[: (h + 1) // 2].sum(), row[(h + 1) // 2:].sum())
    interleaved = max(row[0::2].sum(), row[1::2].sum())
    print(f"per-row cost (1 thread, 8 spp): {row.min() * 1e3:.1f}–{row.max() * 1e3:.1f} ms; "
          f"2-thread split efficiency: contiguous blocks {total / (2 * blocks):.2f}, "
          f"interleaved rows {total / (2 * interleaved):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
