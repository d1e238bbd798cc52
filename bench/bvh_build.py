"""BVH build time and memory for a large triangle mesh.

    .venv/bin/python -m bench.bvh_build [--triangles 1000000]

Builds a closed torus mesh of about N triangles, then times ``compile_scene`` (primitive packing +
SAH BVH build; the BVH kernel is compiled or loaded from cache in a warm-up on a tiny mesh first)
and renders a few samples of it to show the traversal works at that size. Prints peak RSS.
"""

from __future__ import annotations

import argparse
import math
import resource
import tempfile
import time
from pathlib import Path

import numpy as np


def torus(n_triangles: int):
    from renderer.geometry.meshgen import torus as make

    n_minor = max(3, int(math.sqrt(n_triangles / 4)))
    n_major = max(3, n_triangles // (2 * n_minor))
    return make(0.6, 0.25, n_major, n_minor)


def scene_with(vertices, triangles, folder: str):
    """The mesh as the CLI would take it: a PLY file next to the scene, loaded and validated."""
    from renderer.geometry.meshio import write_ply
    from renderer.scene import load_scene

    write_ply(f"{folder}/mesh.ply", vertices, triangles)
    data = {
        "camera": {"position": [0, 1.6, 3.6], "look_at": [0, 0, 0]},
        "film": {"width": 64, "height": 48},
        "render": {"spp": 4},
        "background": [1, 1, 1],
        "materials": {"m": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "mesh", "path": "mesh.ply", "material": "m"}],
    }
    return load_scene(data, allow_paths=True, base_dir=Path(folder))


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--triangles", type=int, default=1_000_000)
    args = parser.parse_args()
    from renderer.geometry.bvh import BVH_WIDTH
    from renderer.render import render_buffer
    from renderer.scene.compile import compile_scene

    folder = tempfile.mkdtemp()
    v, t = torus(1000)
    compile_scene(scene_with(v, t, folder))  # warm the BVH kernel
    v, t = torus(args.triangles)
    start = time.perf_counter()
    scene = scene_with(v, t, folder)
    load = time.perf_counter() - start
    start = time.perf_counter()
    compiled = compile_scene(scene)
    build = time.perf_counter() - start
    start = time.perf_counter()
    buf = render_buffer(compiled, 4)
    render = time.perf_counter() - start
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{len(t):,} triangles: write + read + validate PLY {load:.2f} s; "
          f"compile_scene (packing + SAH BVH) {build:.2f} s, "
          f"{compiled.info['bvh_nodes']:,} {BVH_WIDTH}-wide nodes "
          f"({compiled.info['bvh_binary_nodes']:,} binary), traversal stack {compiled.stack_size}; "
          f"64x48x4 spp render {render:.2f} s, mean {float(np.mean(buf.mean())):.4f}; "
          f"peak RSS {rss:,.0f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
