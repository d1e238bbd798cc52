"""The wavefront kernel's host loop on the CPU, and the scenes it renders.

``render_tile_wavefront`` takes the arguments of ``renderer.render.render_tile`` and returns the
same sample buffer: the tile's active pixels × samples are cut into batches of whole pixels
(``BATCH_PATHS`` paths or a little more), and each batch runs generate, then intersect → shade →
shadow → compact until no path is live, then accumulate (``renderer.wavefront.stages``).

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


def batching(active: np.ndarray, sample_count: int, batch_paths: int):
    """(work list, paths in all, paths a batch): batches of whole pixels, so that a pixel's
    samples are summed in order, as the scalar kernel sums them."""
    work = work_list(active)
    total = len(work) * sample_count
    return work, total, min(total, max(1, batch_paths // sample_count) * sample_count)


def render_tile_wavefront(scene, x0, y0, width, height, sample_start, sample_count, active,
                          batch_paths: int = BATCH_PATHS) -> SampleBuffer:
    """``render_tile`` (arguments checked there) by the wavefront kernel."""
    S = scene.arrays
    buf = SampleBuffer.empty(x0, y0, width, height)
    work, total, n_max = batching(active, sample_count, batch_paths)
    if total == 0:
        return buf
    P = path_state(n_max)
    live = np.empty(n_max, np.int64)
    threads = numba.get_num_threads()
    for g0 in range(0, total, n_max):
        n = min(n_max, total - g0)
        generate(S, P, scene.width, scene.height, scene.seed, x0, y0, width, work, sample_start,
                 sample_count, g0, n, live, threads)
        n_live = n
        for _ in range(MAX_SEGMENTS):
            if n_live == 0:
                break
            intersect(S, P, live, n_live, scene.stack_size, threads)
            shade(S, P, live, n_live, scene.max_depth, threads)
            shadow(S, P, live, n_live, scene.stack_size, threads)
            n_live = compact(P, live, n_live)
        accumulate(P, g0, g0 + n, sample_count, work, buf.sum, buf.sum_sq, buf.count,
                   buf.dropped, width)
    return buf
