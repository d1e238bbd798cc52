"""The Henyey–Greenstein phase function.

p(cos θ) = (1 − g²) / (4π (1 + g² − 2g cos θ)^{3/2}), with θ the angle between the direction the
light was travelling and the direction it scatters into: g > 0 scatters forward (mean cos θ = g),
g < 0 backward. Sampling inverts its CDF exactly (e.g. Prahl's thesis, eq. 3.29, as in MCML):

    cos θ = (1 + g² − ((1 − g²)/(1 − g + 2g ξ))²) / (2g),

and is uniform on the sphere when |g| < 1e-3, where that expression loses precision (it is 0/0 at
g = 0); the pdf differs from the isotropic 1/4π by less than 0.3 % there.
"""

from __future__ import annotations

import math

from renderer.jit import inline_kernel, kernel
from renderer.vecmath import to_world

INV_4PI = 1.0 / (4.0 * math.pi)
ISOTROPIC_G = 1e-3


@kernel
def hg_pdf(cos_theta, g):
    if abs(g) < ISOTROPIC_G:
        return INV_4PI
    denom = 1.0 + g * g - 2.0 * g * cos_theta
    return INV_4PI * (1.0 - g * g) / (denom * math.sqrt(denom))


@kernel
def hg_sample_cos(g, u):
    if abs(g) < ISOTROPIC_G:
        return 1.0 - 2.0 * u
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    cos_theta = (1.0 + g * g - s * s) / (2.0 * g)
    return min(1.0, max(-1.0, cos_theta))


@inline_kernel
def hg_sample(d, g, u1, u2):
    """A new direction scattered from propagation direction ``d``; returns (wi, pdf)."""
    cos_theta = hg_sample_cos(g, u1)
    sin_theta = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    phi = 2.0 * math.pi * u2
    wi = to_world((sin_theta * math.cos(phi), sin_theta * math.sin(phi), cos_theta), d)
    return wi, hg_pdf(cos_theta, g)
