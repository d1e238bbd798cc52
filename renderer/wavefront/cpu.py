"""The wavefront kernel's host loop on the CPU, and the scenes it renders.

``render_tile_wavefront`` takes the arguments of ``renderer.render.render_tile`` and returns the
same sample buffer: the tile's pixels × their samples are cut into batches of whole pixels (at
most ``BATCH_PATHS`` paths, unless one pixel has more), and each batch runs generate, then
intersect → shade → shadow → compact until no path is live, then accumulate
(``renderer.wavefront.stages``).

The kernel covers the untextured, flat-shaded surface materials (``SURFACE_KINDS``) under the
independent sampler. ``unsupported`` names what a scene has beyond that — a translucent method,
backlight, the seed paper's or the student project's methods, diffusion, surfaces a shadow ray
may cross, textures, a mesh's shading normals, the sobol sampler — and ``renderer.render``
renders such a scene with the scalar kernel.
"""

from __future__ import annotations

import numba
import numpy as np

from renderer.film.buffer import SampleBuffer
from renderer.integrators.path import MAX_SEGMENTS
from renderer.materials import bsdf
from renderer.materials.bsdf import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    PHONG,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
)
from renderer.wavefront.stages import accumulate, compact, generate, intersect, shade, shadow
from renderer.wavefront.state import path_state

SURFACE_KINDS = frozenset({DIFFUSE, PHONG, MIRROR, DIELECTRIC, CONDUCTOR, ROUGH_CONDUCTOR,
                           ROUGH_DIELECTRIC})
# Paths a batch: 64 Ki paths' state is ~20 MiB, and a pass of a 320×240 frame at 8 spp is ~9
# batches, enough to keep the threads of every stage busy
BATCH_PATHS = 1 << 16


def unsupported(scene) -> str | None:
    """Why the wavefront kernel cannot render this ``CompiledScene``, or None when it can."""
    S = scene.arrays
    used = set(np.unique(S.mat_kind[S.prim_material]).tolist()) if len(S.prim_material) else set()
    other = sorted(used - SURFACE_KINDS)
    if other:
        names = {v: k.lower() for k, v in vars(bsdf).items() if k.isupper() and type(v) is int}
        return "the material kinds " + ", ".join(names.get(k, str(k)) for k in other)
    if S.null_media[0]:
        return "surfaces a shadow ray crosses"
    if len(S.prim_material) and (S.mat_tex[np.unique(S.prim_material), 1] >= 0.0).any():
        return "textured materials"
    if S.prim_normal.shape[0] > 0:
        return "shading normals"
    if S.sampler[0] != 0:
        return "the sobol sampler"
    return None


def work_list(active: np.ndarray) -> np.ndarray:
    """The tile's active pixels, as row-major indices into the tile."""
    return np.flatnonzero(np.ascontiguousarray(active).ravel()).astype(np.int64)


def pixel_counts(active: np.ndarray | None, sample_count: int, height: int,
                 width: int) -> np.ndarray:
    """(height, width) int32: how many of the samples [sample_start, sample_start +
    sample_count) each pixel takes, from ``render_tile``'s ``active``: None (all), a mask (bool
    or uint8: all where true) or a count a pixel (integers, clipped to [0, sample_count])."""
    if active is None:
        return np.full((height, width), sample_count, np.int32)
    if active.dtype in (np.bool_, np.uint8):
        return np.where(active.astype(bool), sample_count, 0).astype(np.int32)
    return np.clip(active, 0, sample_count).astype(np.int32)


def batching(counts: np.ndarray, batch_paths: int):
    """(work, first, batches) for a tile whose pixels take ``counts`` samples each: ``work`` the
    pixels with any (row-major indices into the tile); ``first[w]`` … ``first[w + 1] − 1`` the
    paths of work item w, so ``first[-1]`` paths in all; ``batches`` (w0, w1) runs of whole
    work items of at most ``batch_paths`` paths (a pixel with more is a batch alone), so that a
    pixel's samples are summed in order, as the scalar kernel sums them. A tile of unequal
    counts (adaptive sampling) is one call, not one a distinct count."""
    flat = np.ascontiguousarray(counts).ravel()
    work = work_list(flat > 0)
    first = np.zeros(len(work) + 1, np.int64)
    np.cumsum(flat[work], out=first[1:])
    batches = []
    w0 = 0
    while w0 < len(work):
        w1 = int(np.searchsorted(first, first[w0] + batch_paths, side="right")) - 1
        w1 = max(w1, w0 + 1)
        batches.append((w0, w1))
        w0 = w1
    return work, first, batches


def render_tile_wavefront(scene, x0, y0, width, height, sample_start, sample_count, active,
                          batch_paths: int = BATCH_PATHS) -> SampleBuffer:
    """``render_tile`` (arguments checked there) by the wavefront kernel; ``active`` as there (a
    mask or a count a pixel)."""
    S = scene.arrays
    buf = SampleBuffer.empty(x0, y0, width, height)
    work, first, batches = batching(pixel_counts(active, sample_count, height, width),
                                    batch_paths)
    if not batches:
        return buf
    n_max = max(int(first[w1] - first[w0]) for w0, w1 in batches)
    P = path_state(n_max)
    live = np.empty(n_max, np.int64)
    threads = numba.get_num_threads()
    for w0, w1 in batches:
        g0 = int(first[w0])
        n = int(first[w1]) - g0
        generate(S, P, scene.width, scene.height, scene.seed, x0, y0, width, work, first,
                 sample_start, g0, n, live, threads)
        n_live = n
        for _ in range(MAX_SEGMENTS):
            if n_live == 0:
                break
            intersect(S, P, live, n_live, scene.stack_size, threads)
            shade(S, P, live, n_live, scene.max_depth, threads)
            shadow(S, P, live, n_live, scene.stack_size, threads)
            n_live = compact(P, live, n_live)
        accumulate(P, w0, w1, first, work, buf.sum, buf.sum_sq, buf.count, buf.dropped, width)
    return buf
