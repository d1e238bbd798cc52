"""The orthonormal basis the kernels build local frames with, and the luminance weights.

Vectors are tuples of floats in the kernels: they stay in registers, no allocation inside the hot
loops. Dot products and the like are written out where they are used.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.jit import kernel

# Rec. 709 luminance Y = Y_R·R + Y_G·G + Y_B·B of a linear RGB colour (ITU-R BT.709): the
# renderer's one copy, for kernels (the scalars fold as constants) and for numpy (LUMINANCE)
Y_R = 0.2126
Y_G = 0.7152
Y_B = 0.0722
LUMINANCE = np.array([Y_R, Y_G, Y_B])


@kernel
def onb(n):
    """Two unit vectors completing ``n`` to a right-handed orthonormal basis.

    Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 2017: branchless and exact at
    n = (0, 0, ±1), where the classic Frisvad construction breaks down.
    """
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    bt = (b, sign + n[1] * n[1] * a, -n[1])
    return t, bt


@kernel
def to_world(v, n):
    """Local (x, y, z) with z along ``n`` → world coordinates."""
    t, b = onb(n)
    return (
        v[0] * t[0] + v[1] * b[0] + v[2] * n[0],
        v[0] * t[1] + v[1] * b[1] + v[2] * n[1],
        v[0] * t[2] + v[1] * b[2] + v[2] * n[2],
    )
