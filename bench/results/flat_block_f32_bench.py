# Scratch microbenchmark of the float32 ray-block flat search (apply flat_block_f32.diff first):
# LUCENT_CACHE_DIR=... PYTHONPATH=. .venv/bin/python bench/results/flat_block_f32_bench.py
import json, time, math, numpy as np
from numba import njit
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from renderer.geometry.flat import flat_filter32, flat_block_scratch, flat_closest, flat_refine, FLAT_MAX, FLAT_BLOCK
from renderer.jit import kernel
cs = compile_scene(load_scene(json.load(open("examples/cornell_box.json"))))
S = cs.arrays
rng = np.random.default_rng(0)
N = 1 << 16
o = rng.uniform(-0.95, 0.95, (N, 3)); d = rng.normal(size=(N, 3)); d /= np.linalg.norm(d, axis=1)[:, None]
flat32 = S.flat.astype(np.float32)
ray, t32, thr = flat_block_scratch(flat32.shape[1])
@njit(error_model="numpy")
def filt_only(flat32, o, d, ray, t32, thr):
    for b in range(0, o.shape[0], FLAT_BLOCK):
        n = min(FLAT_BLOCK, o.shape[0] - b)
        for j in range(n):
            for a in range(3):
                ray[a, j] = o[b+j, a]; ray[3+a, j] = d[b+j, a]
        flat_filter32(flat32, ray, n, t32, thr)
@njit(error_model="numpy")
def full(flat32, kind, geo, o, d, ray, t32, thr, tt):
    c = 0
    for b in range(0, o.shape[0], FLAT_BLOCK):
        n = min(FLAT_BLOCK, o.shape[0] - b)
        for j in range(n):
            for a in range(3):
                ray[a, j] = o[b+j, a]; ray[3+a, j] = d[b+j, a]
        flat_filter32(flat32, ray, n, t32, thr)
        for j in range(n):
            i = b + j
            tt[i] = flat_refine(kind, geo, (o[i,0],o[i,1],o[i,2]), (d[i,0],d[i,1],d[i,2]), math.inf, t32, thr, j)[0]
    return c
@njit(error_model="numpy")
def ref(flat, kind, geo, o, d, tt):
    out = np.empty((3, FLAT_MAX))
    for i in range(o.shape[0]):
        tt[i] = flat_closest(flat, kind, geo, (o[i,0],o[i,1],o[i,2]), (d[i,0],d[i,1],d[i,2]), math.inf, out)[0]
t1 = np.empty(N); t2 = np.empty(N)
def tm(f):
    f(); best=1e9
    for _ in range(7):
        t0=time.perf_counter(); f(); best=min(best,time.perf_counter()-t0)
    return best/N*1e9
print("filter", tm(lambda: filt_only(flat32, o, d, ray, t32, thr)))
print("full", tm(lambda: full(flat32, S.prim_kind, S.prim_geo, o, d, ray, t32, thr, t2)))
print("ref", tm(lambda: ref(S.flat, S.prim_kind, S.prim_geo, o, d, t1)))
print("cands/ray", full(flat32, S.prim_kind, S.prim_geo, o, d, ray, t32, thr, t2)/N, "equal", (t1==t2).mean())
