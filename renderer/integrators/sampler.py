"""Which random number each decision of a path uses: the integrators' dimensions.

Dimensions 0 and 1 jitter the pixel; each path segment then uses the ``DIMS_PER_BOUNCE``
dimensions that follow, always the same ones for the same role (0–2 light sample, 3–5 BSDF or
phase sample, 6 roulette, 7 free flight), so one sample's path is a pure function of (seed,
pixel, sample index) — see ``renderer.rng``.
"""

from __future__ import annotations

import numpy as np

from renderer.jit import kernel
from renderer.rng import sobol_value, uniform

DIMS_PER_BOUNCE = 8
PIXEL_SEED_SALT = np.uint64(0x5D1E5EEDC0FFEE11)
SOBOL_VERTICES = 2  # vertices whose samples the sobol sampler stratifies
SOBOL_BLOCKS = 1 + 5 * SOBOL_VERTICES  # its sequences: the camera's, then five a vertex (draw)


@kernel
def draw(S, key, dim, k, sidx, sob):
    """Value ``k`` of the block of dimensions that starts at ``dim``: independent (``uniform``),
    except at the first ``SOBOL_VERTICES`` vertices under the sobol sampler, where the light
    sample (k 0: the light, k 1-2: the point on it), the BSDF sample (k 3: the lobe, k 4-5: the
    direction) and the free flight (k 7) of each vertex come from their own shuffled, scrambled
    (0,2)-sequences (roulette, k 6, stays independent). ``sob`` holds the pixel's seeds of those
    sequences (``sobol_block_seeds``: row 0 the camera's, then five a vertex)."""
    if S.sampler[0] == 1 and dim < 2 + SOBOL_VERTICES * DIMS_PER_BOUNCE and k != 6:
        base = 1 + 5 * ((dim - 2) // DIMS_PER_BOUNCE)  # block 0 is the camera's
        if k == 0:
            b, c = base, 0
        elif k <= 2:
            b, c = base + 1, k - 1
        elif k == 3:
            b, c = base + 2, 0
        elif k <= 5:
            b, c = base + 3, k - 4
        else:
            b, c = base + 4, 0
        return sobol_value(sidx, sob[b, 0], sob[b, 1 + c], c)
    return uniform(key, dim + k)
