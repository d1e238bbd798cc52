"""The wavefront stages as numba.cuda kernels: one CUDA thread a path.

Each kernel calls the per-path function its CPU stage calls (``renderer.wavefront.stages``):
numba's CUDA target compiles a CPU-jitted function called from a kernel as a device function of
the same source, so the two kernels share every line of the path tracer (the scene's
intersection, BSDFs, lights and random numbers included). What differs is the host side: the
scene and path state live on the device, each thread has its own traversal stack
(``cuda.local.array``), and compaction appends the live paths to a new queue with an atomic
counter. The queue's order then varies from run to run, but a path's result depends on its own
slot only, and accumulation adds each pixel's samples in sample order, so the image does not.

Launches are dear from Python: numba passes every field of the scene and path state as
kernel arguments (0.30–0.35 ms an empty launch on an H200), and running the stages costs five
launches a segment. ``finish_kernel`` instead traces each path to its end in one thread, in one
launch; a batch runs stage by stage only while more than ``tail`` of its paths are live. On an
H200 the default, ``tail`` 1 (one thread a path from the start), was 2.1–5.1× faster than any
smaller share (docs/performance.md, "On a GPU"). The scene's arrays stay on the device between
the tiles of a scene, and so does the path state between batches (the largest so far).

The stages cover what the CPU wavefront kernel covers (surface materials, the independent
sampler). Every other scene runs ``path_kernel``: the scalar kernel's own ``trace_path``, one
thread a path, whose buffers are the scalar kernel's (its 120 s compile is the price of every
method's code in one kernel).

The CUDA simulator runs these kernels on the CPU in Python (``NUMBA_ENABLE_CUDASIM=1``, with
``NUMBA_DISABLE_JIT=1`` so the shared functions are plain Python too): that is how the tests
check them (tests/renderer/wavefront/test_gpu.py). On an H200 their sample buffers equal the
CPU wavefront kernel's (``python -m bench.gpu_speed``).
"""

from __future__ import annotations

import numpy as np
from numba import cuda, float64, int64, uint64

from renderer.film.buffer import SampleBuffer
from renderer.geometry.flat import FLAT_MAX
from renderer.integrators.path import (
    MAX_SEGMENTS,
    camera_sample,
    pixel_sequence_seeds,
    trace_path,
)
from renderer.integrators.sampler import SOBOL_BLOCKS
from renderer.materials.bsdf import N_PARAMS
from renderer.rng import sample_key
from renderer.wavefront import gpu_missing
from renderer.wavefront.cpu import batching, pixel_counts, unsupported
from renderer.wavefront.stages import (
    accumulate_one,
    generate_one,
    intersect_one,
    shade_one,
    shadow_one,
    work_sample,
)
from renderer.wavefront.state import path_state

# Entries of a thread's traversal stack (a compile-time size on the device): a wide tree of up to
# (STACK − 2) / 7 = 36 levels, far more than compile_scene builds for a million triangles
STACK = 256
THREADS = 128  # a block
# Paths a batch on a GPU: an H200 holds 132 × 2048 threads in flight, so the CPU's 64 Ki paths
# would leave most of it idle. 4 Mi paths' state is ~1.3 GiB; on an H200 2^22 paths a batch beat
# 2^20 by 6–7 % and 2^24 at most 3 % more (bench.gpu_speed --grid, docs/performance.md)
GPU_BATCH_PATHS = 1 << 22
# With at most this share of a batch's paths live, finish_kernel traces the rest in one launch.
# 1: every path in one thread from the start. On an H200 that was 2.1–5.1× faster than any
# share below it at every batch size: the stages' launches and compactions cost more than the
# threads' divergence does (bench.gpu_speed --grid)
TAIL = 1.0


@cuda.jit
def generate_kernel(S, P, width, height, seed, x0, y0, tile_w, work, first, sample_start, g0, n,
                    live):
    i = cuda.grid(1)
    if i < n:
        generate_one(S, P, i, width, height, seed, x0, y0, tile_w, work, first, sample_start,
                     g0 + i)
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
def finish_kernel(S, P, live, n_live, max_depth, segments_left):
    """Each live path to its end, segment after segment in one thread: what the queue's trace,
    shade, shadow and compact launches would do to it (a path that shade ends still has its
    shadow ray traced)."""
    j = cuda.grid(1)
    if j < n_live:
        i = live[j]
        stack = (cuda.local.array(STACK, int64), cuda.local.array(STACK, float64),
                 cuda.local.array((3, FLAT_MAX), float64))
        for _ in range(segments_left):
            if P.alive[i] == 0:
                break
            intersect_one(S, P, i, stack)
            shade_one(S, P, i, max_depth)
            shadow_one(S, P, i, stack)


@cuda.jit
def path_kernel(S, P, width, height, seed, max_depth, x0, y0, tile_w, work, first, sample_start,
                g0, n):
    """Path g0 + i of the tile's work in slot i, one thread each, by the scalar kernel's own
    ``trace_path``: every material and method it renders (the translucent ones, textures, shading
    normals, the sobol sampler), which the stages do not cover. The radiance goes to ``P.L[i]``
    and the path's segments to ``P.segments[i]``, for ``accumulate_kernel``."""
    i = cuda.grid(1)
    if i < n:
        _, s, x, y = work_sample(g0 + i, x0, y0, tile_w, work, first, sample_start)
        pixel = y * width + x
        sob = cuda.local.array((SOBOL_BLOCKS, 3), uint64)
        pixel_sequence_seeds(S, seed, pixel, sob)
        key = sample_key(seed, pixel, s)
        o, d = camera_sample(S, width, height, x, y, s, key, sob)
        stack = (cuda.local.array(STACK, int64), cuda.local.array(STACK, float64),
                 cuda.local.array((3, FLAT_MAX), float64))
        scratch = cuda.local.array(N_PARAMS, float64)
        r, gr, b, segments = trace_path(S, o, d, key, stack, max_depth, s, sob, scratch)
        P.L[i, 0] = r
        P.L[i, 1] = gr
        P.L[i, 2] = b
        P.segments[i] = segments


@cuda.jit
def compact_kernel(P, live, n_live, out, count):
    """Append the live paths of the queue to ``out`` (``count[0]`` of them so far)."""
    j = cuda.grid(1)
    if j < n_live:
        i = live[j]
        if P.alive[i] != 0:
            out[cuda.atomic.add(count, 0, 1)] = i


@cuda.jit
def accumulate_kernel(P, w0, w1, first, work, out_sum, out_sum_sq, out_count, out_dropped,
                      out_segments, tile_w, segments):
    """A thread a pixel of the batch w0 … w1 − 1: its samples, in sample order; with
    ``segments`` (the path kernel's batches) their path segments too."""
    w = w0 + cuda.grid(1)
    if w < w1:
        g0 = first[w0]
        accumulate_one(P, w, g0, first, work, out_sum, out_sum_sq, out_count, out_dropped,
                       tile_w)
        if segments:
            slot = work[w]
            row = slot // tile_w
            for g in range(first[w], first[w + 1]):
                out_segments[row, slot - row * tile_w] += P.segments[g - g0]


def _blocks(n: int) -> int:
    return max(1, -(-n // THREADS))


def _accumulate(P, w0, w1, first, work, out, tile_w, segments):
    """Add the batch of work items w0 … w1 − 1 (radiance in ``P.L``, with ``segments`` the
    paths' segments in ``P.segments``) to the buffers ``out``."""
    accumulate_kernel[_blocks(w1 - w0), THREADS](P, w0, w1, first, work, *out, tile_w, segments)


def to_device(arrays):
    """A namedtuple of host arrays as the same namedtuple of device arrays."""
    return type(arrays)(*(cuda.to_device(np.ascontiguousarray(a)) for a in arrays))


# The last scene's arrays on the device, and path state for the largest batch so far: a worker
# renders many tiles × passes of one scene in a row (the host arrays are held, so an id is not
# reused)
_resident: dict[str, tuple] = {}


def _scene_on_device(scene):
    held = _resident.get("scene")
    if held is None or held[0] is not scene.arrays:
        held = (scene.arrays, to_device(scene.arrays))
        _resident["scene"] = held
    return held[1]


def _paths_on_device(n_max: int):
    """Path state for at least ``n_max`` paths: a smaller batch (an edge tile, fewer samples a
    pass) reuses the larger state already there."""
    held = _resident.get("paths")
    if held is None or held[0] < n_max:
        _resident.pop("paths", None)  # free the old state before allocating the new
        held = (n_max, to_device(path_state(n_max)), cuda.device_array(n_max, np.int64),
                cuda.device_array(n_max, np.int64), cuda.device_array(1, np.int64))
        _resident["paths"] = held
    return held[1:]


def render_tile_gpu(scene, x0, y0, width, height, sample_start, sample_count, active=None,
                    batch_paths: int = GPU_BATCH_PATHS, tail: float = TAIL,
                    megakernel: bool | None = None) -> SampleBuffer:
    """``renderer.render.render_tile`` on the GPU; a process that sees no CUDA GPU is refused.

    The scenes the wavefront stages cover (``renderer.wavefront.cpu.unsupported``) run them and
    give the CPU wavefront kernel's sample buffer, up to rounding: ``tail``, at most this share
    of a batch's paths live, ``finish_kernel`` ends them (0: stage by stage to the end; 1: all in
    one thread a path). Every other scene (translucent materials, textures, the sobol sampler…)
    runs ``path_kernel``, the scalar kernel's ``trace_path`` one thread a path, and gives the
    scalar kernel's buffer, up to rounding. ``megakernel``: True runs ``path_kernel`` on any
    scene (to compare the two), False refuses the scenes the stages do not cover."""
    missing = gpu_missing()
    if missing is not None:
        raise RuntimeError(f"the gpu kernel: {missing}")
    reason = unsupported(scene)
    if megakernel is None:
        megakernel = reason is not None
    elif not megakernel and reason is not None:
        raise ValueError(f"the GPU's stage kernels do not cover {reason}")
    if scene.stack_size > STACK:
        raise ValueError(f"the scene's tree needs a stack of {scene.stack_size} > {STACK}")
    buf = SampleBuffer.empty(x0, y0, width, height)
    work, first, batches = batching(pixel_counts(active, sample_count, height, width),
                                    batch_paths)
    if not batches:
        return buf
    n_max = max(int(first[w1] - first[w0]) for w0, w1 in batches)
    S = _scene_on_device(scene)
    P, live, spare, count = _paths_on_device(n_max)
    zero = np.zeros(1, np.int64)
    d_work, d_first = cuda.to_device(work), cuda.to_device(first)
    fields = (buf.sum, buf.sum_sq, buf.count, buf.dropped, buf.segments)
    out = [cuda.to_device(a) for a in fields]
    for w0, w1 in batches:
        g0 = int(first[w0])
        n = int(first[w1]) - g0
        if megakernel:
            path_kernel[_blocks(n), THREADS](S, P, scene.width, scene.height, scene.seed,
                                             scene.max_depth, x0, y0, width, d_work, d_first,
                                             sample_start, g0, n)
            _accumulate(P, w0, w1, d_first, d_work, out, width, True)
            continue
        generate_kernel[_blocks(n), THREADS](S, P, scene.width, scene.height, scene.seed, x0, y0,
                                             width, d_work, d_first, sample_start, g0, n, live)
        n_live = n
        for segment in range(MAX_SEGMENTS):
            if n_live == 0:
                break
            grid = _blocks(n_live), THREADS
            if n_live <= tail * n:
                finish_kernel[grid](S, P, live, n_live, scene.max_depth, MAX_SEGMENTS - segment)
                break
            trace_kernel[grid](S, P, live, n_live, False)
            shade_kernel[grid](S, P, live, n_live, scene.max_depth)
            trace_kernel[grid](S, P, live, n_live, True)
            count.copy_to_device(zero)
            compact_kernel[grid](P, live, n_live, spare, count)
            n_live = int(count.copy_to_host()[0])
            live, spare = spare, live
        _accumulate(P, w0, w1, d_first, d_work, out, width, False)
    for host, dev in zip(fields, out, strict=True):
        dev.copy_to_host(host)
    return buf
