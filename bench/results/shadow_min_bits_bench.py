"""The microbenchmark behind "the shadow rays' column loop as a vector minimum"
(docs/performance.md, "Tried and not landed"): one thread, 1 M random rays against 18 random
quads, ns a ray.

    PYTHONPATH=. .venv/bin/python bench/results/shadow_min_bits_bench.py

a: the renderer's closest-hit search (flat_planar_t, then the scalar argmin); b, c, c2, c3: argmin
variants built on a vector minimum of the t's bits; d: the scalar occlusion loop with its exit; e:
occlusion as one comparison of that minimum. Prints whether every variant finds the same hits.
"""

import time

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from bench.flat_variants import closest
from renderer.geometry.flat import FLAT_MAX, flat_geometry, flat_planar_t
from renderer.geometry.shapes import INF, QUAD

JIT = {"cache": False, "nogil": True, "fastmath": False, "error_model": "numpy", "_nrt": False}


@intrinsic
def float_bits(typingctx, x):
    if x != types.float64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@njit(inline="always", **JIT)
def renderer_search(flat, o, d, out):
    flat_planar_t(flat, o, d, out)
    return 0


@njit(inline="always", **JIT)
def planar_min(flat, o, d, out):
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    m = float_bits(INF)
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
        miss = (det == 0.0) | (u < 0.0) | (u > 1.0) | (v < 0.0) | (v_far > 1.0) | (not t > 0.0)
        tt = INF if miss else t
        out[0, k] = tt
        out[1, k] = u
        out[2, k] = v
        m = min(m, float_bits(tt))
    return m


@njit(inline="always", **JIT)
def argmin_scalar(out, m):  # a
    return closest(out)


@njit(inline="always", **JIT)
def argmin_index_pass(out, m):  # c: the fused minimum, then a vectorized pass for its index
    n = out.shape[1]
    b = n
    for k in range(n):
        b = min(b, k if float_bits(out[0, k]) == m else n)
    return b if b < n and out[0, b] < INF else -1


@njit(inline="always", **JIT)
def argmin_two_vector_passes(out, m):  # b: the minimum, then its first index, both vectorized
    m = float_bits(INF)
    for k in range(out.shape[1]):
        m = min(m, float_bits(out[0, k]))
    return argmin_index_pass(out, m)


@njit(inline="always", **JIT)
def argmin_find_first(out, m):  # c2: the fused minimum, then the first column that holds it
    if m < float_bits(INF):
        for k in range(out.shape[1]):
            if float_bits(out[0, k]) == m:
                return k
    return -1


@njit(inline="always", **JIT)
def argmin_if_hit(out, m):  # c3: the scalar argmin, skipped when nothing was hit
    return closest(out) if m < float_bits(INF) else -1


@njit(inline="always", **JIT)
def occluded_loop(out, m):  # d: any hit before 1.0, the scalar loop with its exit
    for k in range(out.shape[1]):
        if out[0, k] < 1.0:
            return 1
    return 0


@njit(inline="always", **JIT)
def occluded_min(out, m):  # e: one comparison of the fused minimum
    return 1 if m < float_bits(1.0) else 0


def ray_loop(search, reduce):
    @njit(**JIT)
    def run(flat, origins, dirs, out, hits):
        for i in range(origins.shape[0]):
            o = (origins[i, 0], origins[i, 1], origins[i, 2])
            m = search(flat, o, (dirs[i, 0], dirs[i, 1], dirs[i, 2]), out)
            hits[i] = reduce(out, m)

    return run


V = {
    "a current": ray_loop(renderer_search, argmin_scalar),
    "b bits 2 passes": ray_loop(renderer_search, argmin_two_vector_passes),
    "c fused min": ray_loop(planar_min, argmin_index_pass),
    "c2 min+findfirst": ray_loop(planar_min, argmin_find_first),
    "c3 min+skip": ray_loop(planar_min, argmin_if_hit),
    "d occl current": ray_loop(renderer_search, occluded_loop),
    "e occl fused": ray_loop(planar_min, occluded_min),
}
rng = np.random.default_rng(1)
n = 18
kind = np.full(n, QUAD, np.int8)
flat = flat_geometry(kind, rng.normal(size=(n, 9)))
R = 1_000_000
origins = rng.normal(size=(R, 3))
dirs = rng.normal(size=(R, 3))
dirs /= np.linalg.norm(dirs, axis=1)[:, None]
out = np.zeros((3, FLAT_MAX))
H = {k: np.zeros(R, np.int64) for k in V}
for k, f in V.items():
    f(flat, origins[:10], dirs[:10], out, H[k][:10])
T = {k: [] for k in V}
for _ in range(5):
    for k, f in V.items():
        t0 = time.perf_counter()
        f(flat, origins, dirs, out, H[k])
        T[k].append((time.perf_counter() - t0) / R * 1e9)
for k in V:
    print(f"{k:20s} best {min(T[k]):6.1f} median {sorted(T[k])[2]:6.1f}")
closest_same = all(np.array_equal(H["a current"], H[k]) for k in list(V)[1:5])
print("same closest", closest_same, "same occluded",
      np.array_equal(H["d occl current"], H["e occl fused"]))
