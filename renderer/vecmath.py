"""Small 3-vector helpers on tuples of floats, inlined by numba into the kernels.

Tuples keep vectors in registers: no allocation inside the hot loops.
"""

from __future__ import annotations

import math

from renderer.jit import kernel


@kernel
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel
def mul(a, b):
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


@kernel
def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@kernel
def madd(a, b, s):
    """a + s·b"""
    return (a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s)


@kernel
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def length(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@kernel
def normalize(a):
    inv = 1.0 / math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] * inv, a[1] * inv, a[2] * inv)


@kernel
def neg(a):
    return (-a[0], -a[1], -a[2])


@kernel
def max_abs(a):
    return max(abs(a[0]), abs(a[1]), abs(a[2]))


@kernel
def max_component(a):
    return max(a[0], a[1], a[2])


@kernel
def luminance(c):
    """Rec. 709 luminance of a linear RGB colour."""
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


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
