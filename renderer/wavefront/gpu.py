"""The wavefront stages as numba.cuda kernels: one CUDA thread a path.

Each kernel calls the per-path function its CPU stage calls (``renderer.wavefront.stages``):
numba's CUDA target compiles a CPU-jitted function called from a kernel as a device function of
the same source, so the two kernels share every line of the path tracer (the scene's
intersection, BSDFs, lights and random numbers included). What differs is the host side: the
scene and path state are copied to the device once a tile, each thread has its own traversal
stack (``cuda.local.array``), and compaction appends the live paths to a new queue with an atomic
counter. The queue's order then varies from run to run, but a path's result depends on its own
slot only, and accumulation adds each pixel's samples in sample order, so the image does not.

The CUDA simulator runs these kernels on the CPU in Python (``NUMBA_ENABLE_CUDASIM=1``, with
``NUMBA_DISABLE_JIT=1`` so the shared functions are plain Python too): that is how the tests
check them (tests/renderer/wavefront/test_gpu.py). They have not yet run on a GPU.
"""

from __future__ import annotations

import numpy as np
from numba import cuda, float64, int64

from renderer.film.buffer import SampleBuffer
from renderer.geometry.flat import FLAT_MAX
from renderer.integrators.path import MAX_SEGMENTS
from renderer.wavefront.cpu import BATCH_PATHS, batching, unsupported
from renderer.wavefront.stages import (
    accumulate_one,
    generate_one,
    intersect_one,
    shade_one,
    shadow_one,
)
from renderer.wavefront.state import path_state

# Entries of a thread's traversal stack (a compile-time size on the device): a wide tree of up to
# (STACK − 2) / 7 = 36 levels, far more than compile_scene builds for a million triangles
STACK = 256
THREADS = 128  # a block


@cuda.jit
def generate_kernel(S, P, width, height, seed, x0, y0, tile_w, work, sample_start, sample_count,
                    g0, n, live):
    i = cuda.grid(1)
    if i < n:
        generate_one(S, P, i, width, height, seed, x0, y0, tile_w, work, sample_start,
                     sample_count, g0 + i)
        live[i] = i


@cuda.jit
def trace_kernel(S, P, live, n_live, shadow_rays):
    """Closest hits, or with ``shadow_rays`` the shadow rays, of the live paths."""
    j = cuda.grid(1)
    if j < n_live:
        stack = (cuda.local.array(STACK, int64), cuda.local.array(STACK, float64),
                 cuda.local.array((3, FLAT_MAX), float64))
        if shadow_rays:
            shadow_one(S, P, live[j], stack)
        else:
            intersect_one(S, P, live[j], stack)


@cuda.jit
def shade_kernel(S, P, live, n_live, max_depth):
    j = cuda.grid(1)
    if j < n_live:
        shade_one(S, P, live[j], max_depth)


@cuda.jit
def compact_kernel(P, live, n_live, out, count):
    """Append the live paths of the queue to ``out`` (``count[0]`` of them so far)."""
    j = cuda.grid(1)
    if j < n_live:
        i = live[j]
        if P.alive[i] != 0:
            out[cuda.atomic.add(count, 0, 1)] = i


@cuda.jit
def accumulate_kernel(P, g0, g1, sample_count, work, out_sum, out_sum_sq, out_count, out_dropped,
                      tile_w):
    w = g0 // sample_count + cuda.grid(1)
    if w < (g1 + sample_count - 1) // sample_count:
        accumulate_one(P, w, g0, g1, sample_count, work, out_sum, out_sum_sq, out_count,
                       out_dropped, tile_w)


def _blocks(n: int) -> int:
    return max(1, -(-n // THREADS))


def to_device(arrays):
    """A namedtuple of host arrays as the same namedtuple of device arrays."""
    return type(arrays)(*(cuda.to_device(np.ascontiguousarray(a)) for a in arrays))


def render_tile_gpu(scene, x0, y0, width, height, sample_start, sample_count, active=None,
                    batch_paths: int = BATCH_PATHS) -> SampleBuffer:
    """``renderer.render.render_tile`` on the GPU: the same sample buffer as the wavefront kernel
    on the CPU, up to rounding. Scenes the wavefront kernel does not cover are refused."""
    reason = unsupported(scene)
    if reason is not None:
        raise ValueError(f"the GPU kernel does not cover {reason}")
    if scene.stack_size > STACK:
        raise ValueError(f"the scene's tree needs a stack of {scene.stack_size} > {STACK}")
    if active is None:
        active = np.ones((height, width), np.uint8)
    buf = SampleBuffer.empty(x0, y0, width, height)
    work, total, n_max = batching(active, sample_count, batch_paths)
    if total == 0:
        return buf
    S = to_device(scene.arrays)
    P = to_device(path_state(n_max))
    live, spare = cuda.device_array(n_max, np.int64), cuda.device_array(n_max, np.int64)
    d_work = cuda.to_device(work)
    out = [cuda.to_device(a) for a in (buf.sum, buf.sum_sq, buf.count, buf.dropped)]
    for g0 in range(0, total, n_max):
        n = min(n_max, total - g0)
        generate_kernel[_blocks(n), THREADS](S, P, scene.width, scene.height, scene.seed, x0, y0,
                                             width, d_work, sample_start, sample_count, g0, n,
                                             live)
        n_live = n
        for _ in range(MAX_SEGMENTS):
            if n_live == 0:
                break
            grid = _blocks(n_live), THREADS
            trace_kernel[grid](S, P, live, n_live, False)
            shade_kernel[grid](S, P, live, n_live, scene.max_depth)
            trace_kernel[grid](S, P, live, n_live, True)
            count = cuda.to_device(np.zeros(1, np.int64))
            compact_kernel[grid](P, live, n_live, spare, count)
            n_live = int(count.copy_to_host()[0])
            live, spare = spare, live
        pixels_in = (g0 + n + sample_count - 1) // sample_count - g0 // sample_count
        accumulate_kernel[_blocks(pixels_in), THREADS](P, g0, g0 + n, sample_count, d_work,
                                                       *out, width)
    for host, dev in zip((buf.sum, buf.sum_sq, buf.count, buf.dropped), out, strict=True):
        dev.copy_to_host(host)
    return buf
