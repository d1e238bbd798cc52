"""Variants of the flat search's planar test, timed against the renderer's own (one thread).

    .venv/bin/python -m bench.flat_variants [--rays 1000000] [--rounds 5]

The seed boxes spend over half their time in ``renderer.geometry.flat`` (docs/performance.md,
"Where the time goes"). This script times, per ray over 24 columns of 18 random quads (the Cornell
box's count, padded as ``flat_geometry`` pads it), rays in random directions from random points:

- ``moller-trumbore``: the renderer's ``flat_planar_t`` (Möller–Trumbore, ~36 flops a column,
  inlined into its caller) and the closest-hit reduction of ``flat_closest``; ``the same,
  called``: that loop as a function call, as the renderer had it until the call was found to
  cost ~10 ns of a ~50 ns query;
- ``dual basis``: the plane's normal and offset and the edges' dual vectors stored (13 rows), t
  from the plane, u and v as dot products of the hit point (~20 flops a column), same reduction;
- ``loads + reduction``: the loop that only reads every column, and the reduction: the floor;
- ``two passes`` / ``one pass, two rays``: a closest-hit ray and a second ray from the same point
  (a shadow ray's any-hit test), as two loops or as one loop computing both rays' hits.

Every variant's column loop is inlined into the ray loop, as ``flat_planar_t`` is in the
renderer's queries, except ``the same, called``. Rounds alternate the variants; each prints its
best and worst ns. Every variant must find the renderer's closest quad for every ray (checked).
Record results in docs/performance.md ("Tried and not landed", "The flat loop inlined").
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit

from renderer.geometry.flat import FLAT_MAX, flat_geometry, flat_planar_t
from renderer.geometry.shapes import INF, QUAD

JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy", "_nrt": False}


def dual_geometry(flat: np.ndarray, n: int) -> np.ndarray:
    """The dual-basis store: origin (0:3), normal n = e1 × e2 (3:6), the dual vectors
    a = (e2 × n)/|n|² (6:9) and b = (n × e1)/|n|² (9:12), so that p − o = u e1 + v e2 has
    u = a·(p − o), v = b·(p − o); row 12: 1.0 for a triangle."""
    out = np.zeros((13, flat.shape[1]))
    for k in range(n):
        o, e1, e2 = flat[0:3, k], flat[3:6, k], flat[6:9, k]
        normal = np.cross(e1, e2)
        n2 = normal @ normal
        out[0:3, k], out[3:6, k] = o, normal
        out[6:9, k] = np.cross(e2, normal) / n2
        out[9:12, k] = np.cross(normal, e1) / n2
        out[12, k] = flat[9, k]
    return out


@njit(inline="always", **JIT)
def dual_t(flat, o, d, out):
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    for k in range(min(flat.shape[1], out.shape[1])):
        nx, ny, nz = flat[3, k], flat[4, k], flat[5, k]
        tx, ty, tz = ox - flat[0, k], oy - flat[1, k], oz - flat[2, k]
        dn = dx * nx + dy * ny + dz * nz
        t = -(tx * nx + ty * ny + tz * nz) / dn
        hx, hy, hz = tx + t * dx, ty + t * dy, tz + t * dz
        u = hx * flat[6, k] + hy * flat[7, k] + hz * flat[8, k]
        v = hx * flat[9, k] + hy * flat[10, k] + hz * flat[11, k]
        v_far = u + v if flat[12, k] != 0.0 else v
        miss = (u < 0.0) | (u > 1.0) | (v < 0.0) | (v_far > 1.0) | (not t > 0.0)
        out[0, k] = INF if miss else t
        out[1, k] = u
        out[2, k] = v


@njit(inline="always", **JIT)
def loads_only(flat, o, d, out):
    for k in range(min(flat.shape[1], out.shape[1])):
        out[0, k] = (flat[0, k] + flat[1, k] + flat[2, k] + flat[3, k] + flat[4, k]
                     + flat[5, k] + flat[6, k] + flat[7, k] + flat[8, k] + flat[9, k]) * d[0]


@njit(inline="always", **JIT)
def closest(out):
    best = INF
    b = -1
    for k in range(out.shape[1]):
        if out[0, k] < best:
            best = out[0, k]
            b = k
    return b


@njit(inline="always", **JIT)
def pair_t(flat, o, d, d2, out):
    """flat_planar_t's arithmetic for two rays from o at once: row 0 the first's t, row 3 the
    second's."""
    ox, oy, oz = o[0], o[1], o[2]
    for k in range(min(flat.shape[1], out.shape[1])):
        e1x, e1y, e1z = flat[3, k], flat[4, k], flat[5, k]
        e2x, e2y, e2z = flat[6, k], flat[7, k], flat[8, k]
        tx, ty, tz = ox - flat[0, k], oy - flat[1, k], oz - flat[2, k]
        qx = ty * e1z - tz * e1y
        qy = tz * e1x - tx * e1z
        qz = tx * e1y - ty * e1x
        tri = flat[9, k] != 0.0
        for r in range(2):
            dx, dy, dz = (d[0], d[1], d[2]) if r == 0 else (d2[0], d2[1], d2[2])
            px = dy * e2z - dz * e2y
            py = dz * e2x - dx * e2z
            pz = dx * e2y - dy * e2x
            det = e1x * px + e1y * py + e1z * pz
            inv_det = 1.0 / det
            u = (tx * px + ty * py + tz * pz) * inv_det
            v = (dx * qx + dy * qy + dz * qz) * inv_det
            t = (e2x * qx + e2y * qy + e2z * qz) * inv_det
            v_far = u + v if tri else v
            miss = ((det == 0.0) | (u < 0.0) | (u > 1.0) | (v < 0.0) | (v_far > 1.0)
                    | (not t > 0.0))
            out[3 * r, k] = INF if miss else t


# the same loop as a call (as the renderer had it before 2026-12-01's inliner session)
planar_t_called = njit(**JIT)(flat_planar_t.py_func)


def ray_loop(planar_t):
    """A kernel that runs ``planar_t`` for every ray, then the closest-hit reduction (not cached:
    it closes over ``planar_t``)."""
    @njit(**{**JIT, "cache": False})
    def run(flat, origins, dirs, out, hits):
        for i in range(origins.shape[0]):
            planar_t(flat, (origins[i, 0], origins[i, 1], origins[i, 2]),
                     (dirs[i, 0], dirs[i, 1], dirs[i, 2]), out)
            hits[i] = closest(out)
    return run


run_mt_called = ray_loop(planar_t_called)
run_mt = ray_loop(flat_planar_t)
run_dual = ray_loop(dual_t)
run_loads = ray_loop(loads_only)


@njit(**JIT)
def run_two_passes(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0] - 1):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        flat_planar_t(flat, o, (dirs[i, 0], dirs[i, 1], dirs[i, 2]), out)
        hits[i] = closest(out)
        flat_planar_t(flat, o, (dirs[i + 1, 0], dirs[i + 1, 1], dirs[i + 1, 2]), out)
        for k in range(out.shape[1]):
            if out[0, k] < 1.0:
                hits[i] += 100
                break


@njit(**JIT)
def run_one_pass(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0] - 1):
        pair_t(flat, (origins[i, 0], origins[i, 1], origins[i, 2]),
               (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
               (dirs[i + 1, 0], dirs[i + 1, 1], dirs[i + 1, 2]), out)
        hits[i] = closest(out)
        for k in range(out.shape[1]):
            if out[3, k] < 1.0:
                hits[i] += 100
                break


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rays", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    n = 18
    kind = np.full(n, QUAD, np.int8)
    geo = rng.normal(size=(n, 9))
    flat = flat_geometry(kind, geo)
    dual = dual_geometry(flat, n)
    origins = rng.normal(size=(args.rays, 3))
    dirs = rng.normal(size=(args.rays, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    out = np.zeros((6, FLAT_MAX))
    variants = {"moller-trumbore": (run_mt, flat), "the same, called": (run_mt_called, flat),
                "dual basis": (run_dual, dual),
                "loads + reduction": (run_loads, flat), "two passes": (run_two_passes, flat),
                "one pass, two rays": (run_one_pass, flat)}
    hits = {name: np.zeros(args.rays, np.int64) for name in variants}
    for name, (fn, store) in variants.items():  # compile (or load) and warm
        fn(store, origins[:10], dirs[:10], out, hits[name][:10])
    times: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(args.rounds):
        for name, (fn, store) in variants.items():
            t0 = time.perf_counter()
            fn(store, origins, dirs, out, hits[name])
            times[name].append((time.perf_counter() - t0) / args.rays * 1e9)
    same = (np.array_equal(hits["moller-trumbore"], hits["dual basis"])
            and np.array_equal(hits["moller-trumbore"], hits["the same, called"]))
    print(f"{args.rays:,} rays, 18 quads in {flat.shape[1]} columns, one thread, "
          f"{args.rounds} alternating rounds (ns a ray; the last two: a pair)")
    for name, ts in times.items():
        print(f"{name:<20} best {min(ts):6.1f}  worst {max(ts):6.1f}")
    print(f"the variants find the same closest quad for every ray: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
