"""Closest-hit and shadow-ray queries of a small scene: the flat search against the 8-wide BVH.

    .venv/bin/python -m bench.flat_vs_tree [--rays 400000]

``compile_scene`` searches scenes of at most ``FLAT_MAX`` primitives flat, every primitive in the
vector loop of renderer/geometry/flat.py, and larger ones with the BVH. This script times both
searches on the same primitives, one thread, for random rays (origins uniform in the scene's
bounds shrunk by 5 %, directions uniform on the sphere), in ns a ray:

- the example scenes that are flat (`examples/*.json` of at most FLAT_MAX primitives);
- a room (6 walls) around a low-poly torus of 12 to 224 triangles: a scene the tree culls well,
  which places the crossover;
- with ``--columns``, the flat search over 1 to FLAT_MAX random quads, to show what the store's
  padding to full vectors (flat.FLAT_PAD) buys; ``--pads 4 8`` times each count with each
  padding in turn (n: columns and ns for each), this CPU's against the other's, and
  ``--min-columns`` lowers the store's least width (flat.FLAT_MIN_COLUMNS) to show what it is for.

Record results in docs/performance.md ("Flat scenes").
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from numba import njit

from renderer.geometry.bvh import (
    BVH_WIDTH,
    build_bvh,
    intersect_closest,
    occluded,
    stack_size,
    traversal_stack,
    widen_bvh,
)
from renderer.geometry.flat import (
    FLAT_MAX,
    FLAT_MIN_COLUMNS,
    FLAT_PAD,
    FLAT_ROWS,
    flat_geometry,
    flat_order,
)
from renderer.geometry.shapes import INF, QUAD, TRIANGLE, prim_bounds
from renderer.scene.compile import compile_scene
from renderer.scene.load import load_scene_file

ROOT = Path(__file__).resolve().parents[1]
JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy", "_nrt": False}


@njit(**JIT)
def closest_all(lo, hi, child, count, flat, kind, geo, origins, dirs, stack, out):
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        out[i] = intersect_closest(lo, hi, child, count, flat, kind, geo, o, d, INF, stack)[1]


@njit(**JIT)
def occluded_all(lo, hi, child, count, flat, kind, geo, origins, dirs, stack, out):
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        out[i] = occluded(lo, hi, child, count, flat, kind, geo, o, d, 1.0, stack)


def packed(kind: np.ndarray, geo: np.ndarray, flat: bool, pad: int = FLAT_PAD,
           min_columns: int = FLAT_MIN_COLUMNS):
    """The arrays compile_scene would make, flat (its store padded to ``pad``, at least
    ``min_columns``) or with the tree whatever the count."""
    if flat:
        order = flat_order(kind)
        kind, geo = kind[order], np.ascontiguousarray(geo[order])
        empty = np.zeros((0, 3, BVH_WIDTH))
        none = np.zeros((0, BVH_WIDTH), np.int32)
        return (empty, empty, none, none, flat_geometry(kind, geo, pad, min_columns), kind, geo), 2
    lo, hi = prim_bounds(kind, geo)
    *nodes, order = build_bvh(lo, hi)
    w_lo, w_hi, w_child, w_count, depth = widen_bvh(*nodes)
    kind, geo = kind[order], np.ascontiguousarray(geo[order])
    return (w_lo, w_hi, w_child, w_count, np.zeros((FLAT_ROWS, 0)), kind, geo), depth


def ns_per_ray(arrays, depth, origins, dirs, fn) -> float:
    slots, dist, scratch = traversal_stack(stack_size(depth))
    # Past FLAT_MAX (where compile_scene would not go flat) the scratch must hold every column
    stack = (slots, dist, np.empty((3, max(scratch.shape[1], arrays[4].shape[1]))))
    out = np.empty(len(origins), np.int64)
    fn(*arrays, origins[:8], dirs[:8], stack, out)  # compile or load
    best = INF
    for _ in range(3):
        start = time.perf_counter()
        fn(*arrays, origins, dirs, stack, out)
        best = min(best, time.perf_counter() - start)
    return best / len(origins) * 1e9


def rays(rng, lo, hi, n):
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * 0.95
    origins = rng.uniform(mid - half, mid + half, (n, 3))
    dirs = rng.normal(size=(n, 3))
    return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def compare(label, kind, geo, origins, dirs):
    cells = []
    for fn in (closest_all, occluded_all):
        tree = ns_per_ray(*packed(kind, geo, False), origins, dirs, fn)
        flat = ns_per_ray(*packed(kind, geo, True), origins, dirs, fn)
        cells.append(f"{tree:6.1f} {flat:6.1f} {tree / flat:5.2f}")
    print(f"{label:42s} {len(kind):4d}   " + "   ".join(cells))


def room_and_torus(segments_around: int, segments_tube: int):
    """A 4×4×4 room of quads around a torus (radii 0.7, 0.25) of 2·a·b triangles."""
    a, b = segments_around, segments_tube
    th, ph = np.meshgrid(np.arange(a) * 2 * np.pi / a, np.arange(b) * 2 * np.pi / b,
                         indexing="ij")
    ring = 0.7 + 0.25 * np.cos(ph)
    verts = np.stack([ring * np.cos(th), 0.25 * np.sin(ph), ring * np.sin(th)], -1).reshape(-1, 3)
    tris = []
    for i in range(a):
        for j in range(b):
            p, q = i * b + j, ((i + 1) % a) * b + j
            p1, q1 = i * b + (j + 1) % b, ((i + 1) % a) * b + (j + 1) % b
            tris += [(p, q, q1), (p, q1, p1)]
    tris = np.array(tris)
    v0 = verts[tris[:, 0]]
    torus = np.concatenate([v0, verts[tris[:, 1]] - v0, verts[tris[:, 2]] - v0], axis=1)
    walls = np.array([[-2, -2, -2, 4, 0, 0, 0, 4, 0], [-2, -2, 2, 4, 0, 0, 0, 4, 0],
                      [-2, -2, -2, 0, 4, 0, 0, 0, 4], [2, -2, -2, 0, 4, 0, 0, 0, 4],
                      [-2, -2, -2, 4, 0, 0, 0, 0, 4], [-2, 2, -2, 4, 0, 0, 0, 0, 4]], float)
    kind = np.array([QUAD] * 6 + [TRIANGLE] * len(torus), np.int8)
    return kind, np.concatenate([walls, torus])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rays", type=int, default=400_000)
    parser.add_argument("--columns", action="store_true", help="also scan 1..FLAT_MAX quads")
    parser.add_argument("--pads", type=int, nargs="+", default=[FLAT_PAD], metavar="PAD",
                        help=f"the store's paddings --columns times (this CPU's: {FLAT_PAD})")
    parser.add_argument("--min-columns", type=int, default=FLAT_MIN_COLUMNS,
                        help=f"the store's least width for --columns ({FLAT_MIN_COLUMNS})")
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    print(f"ns a ray, 1 thread, {args.rays:,} random rays; FLAT_MAX {FLAT_MAX}")
    print(f"{'scene':42s} {'prims':>5s}   {'closest: tree   flat  ratio':27s}   "
          f"{'shadow: tree   flat  ratio'}")
    for path in sorted((ROOT / "examples").glob("*.json")):
        try:
            arrays = compile_scene(load_scene_file(path)).arrays
        except (OSError, ValueError):
            continue
        if not 0 < len(arrays.prim_kind) <= FLAT_MAX:
            continue
        lo, hi = prim_bounds(arrays.prim_kind, arrays.prim_geo)
        origins, dirs = rays(rng, lo.min(axis=0), hi.max(axis=0), args.rays)
        compare(path.stem, arrays.prim_kind, arrays.prim_geo, origins, dirs)
    for a, b in ((3, 2), (3, 3), (4, 3), (4, 4), (6, 4), (8, 4), (8, 7), (16, 7)):
        kind, geo = room_and_torus(a, b)
        origins, dirs = rays(rng, np.full(3, -2.0), np.full(3, 2.0), args.rays)
        compare(f"room + torus of {2 * a * b} triangles", kind, geo, origins, dirs)
    if args.columns:
        quads = np.zeros((FLAT_MAX, 9))
        quads[:, 0:3] = rng.uniform(-1, 1, (FLAT_MAX, 3))
        quads[:, 3:9] = rng.normal(size=(FLAT_MAX, 6)) * 0.3
        origins, dirs = rays(rng, np.full(3, -1.0), np.full(3, 1.0), args.rays)
        cells = []
        for n in range(1, FLAT_MAX + 1):
            kind = np.full(n, QUAD, np.int8)
            runs = []
            for pad in args.pads:
                arrays, depth = packed(kind, np.ascontiguousarray(quads[:n]), True, pad,
                                       args.min_columns)
                ns = ns_per_ray(arrays, depth, origins, dirs, closest_all)
                runs.append(f"{arrays[4].shape[1]} col {ns:.0f}" if len(args.pads) > 1
                            else f"{ns:.0f}")
            cells.append(f"{n}: " + " / ".join(runs))
        pads = " / ".join(f"pad {p}" for p in args.pads)
        print(f"flat closest hit over n random quads, ns a ray ({pads}):", ", ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
