"""Small scenes without a tree: every primitive tested at once, in the CPU's vector lanes.

A scene of two dozen primitives or fewer (a Cornell box is 18 quads) is searched faster by testing
all of them than by walking a BVH: the tree's box tests, stack and branches cost more than the
handful of primitives they rule out. Tested one by one that would not hold, but the planar test
(Möller–Trumbore, ``shapes.intersect_parallelogram``) has no branch, so one loop over the
primitives, their coordinates stored by column (``flat_geometry``), is vectorized by LLVM: 8
primitives per AVX-512 instruction, 4 per AVX2 one. On the seed paper's boxes that finds the
closest of 18 quads 1.8x as fast as the 8-wide BVH does (docs/performance.md, "Flat scenes").

Spheres have no such test (a square root and two roots); they come first in a flat scene's
primitive order and are tested one by one before the loop, which sees them as degenerate quads
(zero edges: determinant 0, a miss). The loop is the scalar test's arithmetic, so hits are those
of ``intersect_prim`` bit for bit (t, u and v); of two primitives hit at exactly the same
distance (coplanar faces) the first in order wins.
"""

from __future__ import annotations

import numpy as np

from renderer.geometry.shapes import INF, SPHERE, TRIANGLE, intersect_sphere
from renderer.jit import inline_kernel

# Scenes with at most this many primitives are flat (compile_scene). Past it the tree wins where
# it culls well: a room around a low-poly torus is found 1.1x as fast flat at 30 primitives but
# 0.84x at 38, and its shadow rays (any hit, early exit) are faster with the tree from 30
# (docs/performance.md, "Flat scenes"; ``python -m bench.flat_vs_tree``)
FLAT_MAX = 24
# Rows of the column store: origin/v0 (0:3), edge1 (3:6), edge2 (6:9), 1.0 for a triangle (9)
FLAT_ROWS = 10
# The store's columns are padded with empty ones (all zero: determinant 0, a miss) to at least
# FLAT_MIN_COLUMNS and a multiple of the loop's vector (vector_pad), so that LLVM's vector loop
# takes every column and none is left to its scalar tail. How LLVM compiles the loop depends on
# the CPU. With AVX-512 (Zen 4, the Xeons of 2026-12-01): 16 lanes an iteration, then one
# vector of 8, then one primitive at a time, and a primitive left to the scalar tail costs as much
# as 5 in a vector (15 primitives took 109 ns a ray, 16 took 39 ns). With AVX2 and no AVX-512
# (Zen 3): one vector of 4 doubles an iteration, taken only from 16 columns on (fewer go
# through the scalar loop whole: 8 columns 101-105 ns a ray, 16 columns 64-70), then the scalar
# tail; so there the 18 quads of the Cornell box fill 20 columns, not 24 (docs/performance.md,
# "The flat store padded to the CPU's vector"; ``python -m bench.flat_vs_tree --columns``).
FLAT_MIN_COLUMNS = 16


def vector_pad(features: str) -> int:
    """The column multiple for a CPU with these LLVM features (``+avx2,-avx512f,…``): 4 with AVX2
    and no AVX-512, where LLVM vectorizes the loop by 4 doubles; otherwise 8, a multiple of every
    vector width (AVX-512's 8 doubles, measured; SSE's and NEON's 2, not measured here)."""
    enabled = {f[1:] for f in features.split(",") if f.startswith("+")}
    return 4 if "avx2" in enabled and "avx512f" not in enabled else 8


def _target_features() -> str:
    """The features numba compiles for: ``NUMBA_CPU_FEATURES`` when set, else the host's."""
    from llvmlite import binding
    from numba.core import config

    if config.CPU_FEATURES is not None:
        return config.CPU_FEATURES
    return binding.get_host_cpu_features().flatten()


# The padding only decides which empty columns the loop tests after the primitives: hits, and
# so images, are the same for any of them (tests/renderer/geometry/test_intersect.py).
FLAT_PAD = vector_pad(_target_features())


def flat_order(prim_kind: np.ndarray) -> np.ndarray:
    """The primitive order of a flat scene: spheres first, the rest as given."""
    return np.argsort(prim_kind != SPHERE, kind="stable")


def flat_geometry(prim_kind: np.ndarray, prim_geo: np.ndarray, pad: int = FLAT_PAD,
                  min_columns: int = FLAT_MIN_COLUMNS) -> np.ndarray:
    """The column store the vector loop reads, (FLAT_ROWS, n padded to a multiple of ``pad``, at
    least ``min_columns``): column k is primitive k, spheres and the padding are left all zero.
    No primitives, no columns."""
    n = len(prim_kind)
    columns = max(min_columns, -(-n // pad) * pad) if n else 0
    flat = np.zeros((FLAT_ROWS, columns))
    planar = np.zeros(columns, bool)
    planar[:n] = prim_kind != SPHERE
    flat[:9, planar] = prim_geo[prim_kind != SPHERE].T
    flat[9, :n] = prim_kind == TRIANGLE
    return flat


@inline_kernel
def flat_planar_t(flat, o, d, out):
    """(t, u, v) of every planar primitive k along the ray into out[:, k] (t = inf on a miss):
    intersect_parallelogram's arithmetic, one primitive per vector lane. Columns past the
    scratch's (FLAT_MAX, compile_scene never makes more) are not searched. Inlined: as a call it
    cost ~10 ns of a ~50 ns query, and flat scenes rendered ~20 % slower (``bench.flat_variants``,
    ``bench.ab_speed``; docs/performance.md, "The flat loop inlined")."""
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    for k in range(min(flat.shape[1], out.shape[1])):
        e1x, e1y, e1z = flat[3, k], flat[4, k], flat[5, k]
        e2x, e2y, e2z = flat[6, k], flat[7, k], flat[8, k]
        px = dy * e2z - dz * e2y
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        inv_det = 1.0 / det
        tx, ty, tz = ox - flat[0, k], oy - flat[1, k], oz - flat[2, k]
        u = (tx * px + ty * py + tz * pz) * inv_det
        qx = ty * e1z - tz * e1y
        qy = tz * e1x - tx * e1z
        qz = tx * e1y - ty * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv_det
        t = (e2x * qx + e2y * qy + e2z * qz) * inv_det
        v_far = u + v if flat[9, k] != 0.0 else v
        miss = ((det == 0.0) | (u < 0.0) | (u > 1.0) | (v < 0.0) | (v_far > 1.0)
                | (not t > 0.0))
        out[0, k] = INF if miss else t
        out[1, k] = u
        out[2, k] = v


@inline_kernel
def flat_closest(flat, prim_kind, prim_geo, o, d, t_max, out):
    """Closest hit within (0, t_max) of a flat scene: (t, prim, u, v), prim = -1 on a miss.
    ``out`` is (3, FLAT_MAX) scratch (``traversal_stack``)."""
    best_t = t_max
    best = -1
    k = 0
    while k < prim_kind.shape[0] and prim_kind[k] == SPHERE:
        t = intersect_sphere(o, d, prim_geo[k])[0]
        if t < best_t:
            best_t = t
            best = k
        k += 1
    flat_planar_t(flat, o, d, out)
    for k in range(min(flat.shape[1], out.shape[1])):
        if out[0, k] < best_t:
            best_t = out[0, k]
            best = k
    if best < 0:
        return INF, -1, 0.0, 0.0
    if prim_kind[best] == SPHERE:
        return best_t, best, 0.0, 0.0
    return best_t, best, out[1, best], out[2, best]


@inline_kernel
def flat_occluded(flat, prim_kind, prim_geo, o, d, t_max, out):
    """True when a primitive of a flat scene lies on the ray within (0, t_max)."""
    k = 0
    while k < prim_kind.shape[0] and prim_kind[k] == SPHERE:
        if intersect_sphere(o, d, prim_geo[k])[0] < t_max:
            return True
        k += 1
    flat_planar_t(flat, o, d, out)
    for k in range(min(flat.shape[1], out.shape[1])):
        if out[0, k] < t_max:
            return True
    return False
