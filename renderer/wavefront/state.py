"""Structure-of-arrays state of a batch of paths (pbrt-v4's SOA work items, one array a field).

Every field is indexed by the path's slot in the batch; queues of live paths hold slots, so a
stage reads and writes its paths' fields in place and compaction moves no state. float64
throughout: the wavefront kernel does the scalar kernel's arithmetic on the same values, so its
paths are the scalar kernel's paths (tests/renderer/wavefront/test_wavefront.py compares the two
images to rounding), which float32 state would not keep.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

PathState = namedtuple(
    "PathState",
    [
        # the sample: its pixel's index in the tile's work list, its global sample index and the
        # counter-based generator's key (renderer.rng.sample_key)
        "work", "sample", "key",
        # the ray: origin, direction (n, 3)
        "o", "d",
        # throughput β, radiance gathered so far (n, 3); the η² product of refractions
        "beta", "L", "eta_scale",
        # scattering events so far; the first random dimension of the next segment
        "depth", "dim",
        # MIS of the next emitter found: 1 when the last vertex took no light sample (camera,
        # delta BSDF), the BSDF pdf of the last bounce and the point it left from
        "unweighted", "prev_pdf", "prev_p",
        # 1 while the path goes on
        "alive",
        # the closest hit of the current ray: distance, primitive (−1: escaped), (u, v)
        "hit_t", "hit_prim", "hit_u", "hit_v",
        # the light sample's shadow ray from the last vertex: point, normal, direction, distance
        # to the light (< 0: none), the primitive's scale, and β·f·Li·w/pdf if unoccluded
        "shadow_p", "shadow_n", "shadow_wi", "shadow_t", "shadow_scale", "shadow_c",
        # path segments traced, where a whole path ran in one call (the GPU's path_kernel): the
        # cost adaptive sampling weighs, as the scalar kernel reports it
        "segments",
    ],
)


def path_state(n: int) -> PathState:
    """Room for n paths (values are written by the generate stage)."""
    v3 = lambda: np.zeros((n, 3))  # noqa: E731
    return PathState(
        work=np.zeros(n, np.int64), sample=np.zeros(n, np.int64), key=np.zeros(n, np.uint64),
        o=v3(), d=v3(), beta=v3(), L=v3(), eta_scale=np.zeros(n),
        depth=np.zeros(n, np.int64), dim=np.zeros(n, np.int64),
        unweighted=np.zeros(n, np.uint8), prev_pdf=np.zeros(n), prev_p=v3(),
        alive=np.zeros(n, np.uint8),
        hit_t=np.zeros(n), hit_prim=np.zeros(n, np.int64), hit_u=np.zeros(n), hit_v=np.zeros(n),
        shadow_p=v3(), shadow_n=v3(), shadow_wi=v3(), shadow_t=np.zeros(n),
        shadow_scale=np.zeros(n), shadow_c=v3(), segments=np.zeros(n, np.int64),
    )
