"""Smooth dielectric: exact Fresnel, Snell refraction, total internal reflection.

Row (``pack_dielectric``): ``IOR`` (the interior index; the exterior is vacuum, η = 1) and
``ABSORPTION`` σa (RGB, per unit length, three slots), applied as Beer–Lambert transmittance
exp(−σa·d) over the distance d a path travels inside (see the integrator). Every material whose
boundary is this one (``translucent``, ``diffusion``) keeps its ior in the same ``IOR`` slot.

Reflection and refraction are chosen with probabilities F and 1 − F, so the sample weight is 1 for
reflection and (η_i/η_t)² for refraction: radiance scales by η² across an interface (Veach's
thesis, §5.2; pbrt-v4 and Mitsuba 3 do the same in radiance mode), which makes a camera path that
enters glass carry 1/η² and one that leaves it η².
"""

from __future__ import annotations

import math

from renderer.jit import block, kernel
from renderer.materials.fresnel import fresnel_dielectric, reflect, refract

IOR = 0
ABSORPTION = 1
ROUGHNESS = 4  # GGX α of the boundary (renderer/materials/rough_dielectric.py); 0: smooth


def pack_dielectric(p, m) -> None:
    """Write a ``dielectric`` material's row into ``p``."""
    p[IOR] = m.ior
    p[ABSORPTION:ABSORPTION + 3] = m.absorption
    p[ROUGHNESS] = m.roughness


@block
def absorbed(param, t, br, bg, bb):
    """β after t of the interior: Beer–Lambert, exp(−σa·t) per channel."""
    return (br * math.exp(-param[ABSORPTION] * t), bg * math.exp(-param[ABSORPTION + 1] * t),
            bb * math.exp(-param[ABSORPTION + 2] * t))


@kernel
def dielectric_sample(param, wo, n, uc):
    """Returns (wi, weight): n is the outward normal of the closed shape."""
    ior = param[IOR]
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    if cos_o >= 0.0:
        eta = ior  # arriving from outside
        ns = n
    else:
        eta = 1.0 / ior
        ns = (-n[0], -n[1], -n[2])
        cos_o = -cos_o
    f, cos_t = fresnel_dielectric(cos_o, eta)
    if uc < f:
        return reflect(wo, ns), 1.0
    wt = refract(wo, ns, eta, cos_o, cos_t)
    return wt, 1.0 / (eta * eta)
