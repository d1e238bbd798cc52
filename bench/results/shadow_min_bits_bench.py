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
def closest(out):
    best = INF
    b = -1
    for k in range(out.shape[1]):
        if out[0, k] < best:
            best = out[0, k]
            b = k
    return b


@njit(inline="always", **JIT)
def closest_bits(out):
    n = out.shape[1]
    m = float_bits(INF)
    for k in range(n):
        m = min(m, float_bits(out[0, k]))
    b = n
    for k in range(n):
        b = min(b, k if float_bits(out[0, k]) == m else n)
    return b if b < n and out[0, b] < INF else -1


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


@njit(**JIT)
def run_a(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0]):
        flat_planar_t(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        hits[i] = closest(out)


@njit(**JIT)
def run_b(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0]):
        flat_planar_t(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        hits[i] = closest_bits(out)


@njit(**JIT)
def run_c(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0]):
        m = planar_min(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        n = out.shape[1]
        b = n
        for k in range(n):
            b = min(b, k if float_bits(out[0, k]) == m else n)
        hits[i] = b if b < n and out[0, b] < INF else -1


@njit(**JIT)
def run_d(flat, origins, dirs, out, hits):  # occluded-style: any hit below 1.0
    for i in range(origins.shape[0]):
        flat_planar_t(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        h = 0
        for k in range(out.shape[1]):
            if out[0, k] < 1.0:
                h = 1
                break
        hits[i] = h


@njit(**JIT)
def run_e(flat, origins, dirs, out, hits):
    lim = float_bits(1.0)
    for i in range(origins.shape[0]):
        m = planar_min(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        hits[i] = 1 if m < lim else 0


rng = np.random.default_rng(1)
n = 18
kind = np.full(n, QUAD, np.int8)
geo = rng.normal(size=(n, 9))
flat = flat_geometry(kind, geo)
R = 1_000_000
origins = rng.normal(size=(R, 3))
dirs = rng.normal(size=(R, 3))
dirs /= np.linalg.norm(dirs, axis=1)[:, None]
out = np.zeros((3, FLAT_MAX))


@njit(**JIT)
def run_c2(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0]):
        m = planar_min(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        b = -1
        if m < float_bits(INF):
            for k in range(out.shape[1]):
                if float_bits(out[0, k]) == m:
                    b = k
                    break
        hits[i] = b


@njit(**JIT)
def run_c3(flat, origins, dirs, out, hits):
    for i in range(origins.shape[0]):
        m = planar_min(
            flat,
            (origins[i, 0], origins[i, 1], origins[i, 2]),
            (dirs[i, 0], dirs[i, 1], dirs[i, 2]),
            out,
        )
        b = -1
        if m < float_bits(INF):
            b = closest(out)
        hits[i] = b


V = {
    "c2 min+findfirst": run_c2,
    "c3 min+skip": run_c3,
    "a current": run_a,
    "b bits 2 passes": run_b,
    "c fused min": run_c,
    "d occl current": run_d,
    "e occl fused": run_e,
}
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
print(
    "same closest",
    np.array_equal(H["a current"], H["b bits 2 passes"]),
    np.array_equal(H["a current"], H["c fused min"]),
    np.array_equal(H["a current"], H["c2 min+findfirst"]),
    np.array_equal(H["a current"], H["c3 min+skip"]),
    "same occl",
    np.array_equal(H["d occl current"], H["e occl fused"]),
)
print("hit frac", (H["a current"] >= 0).mean(), H["d occl current"].mean())
