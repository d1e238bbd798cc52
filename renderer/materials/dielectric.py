"""Smooth dielectric: exact Fresnel, Snell refraction, total internal reflection.

Parameters: ``ior`` in ``param[0]`` (interior index; the exterior is vacuum, η = 1) and
``absorption`` σa (RGB, per unit length) in ``param[1:4]``, applied as Beer–Lambert transmittance
exp(−σa·d) over the distance d a path travels inside (see the integrator).

Reflection and refraction are chosen with probabilities F and 1 − F, so the sample weight is 1 for
reflection and (η_i/η_t)² for refraction: radiance scales by η² across an interface (Veach's
thesis, §5.2; pbrt-v4 and Mitsuba 3 do the same in radiance mode), which makes a camera path that
enters glass carry 1/η² and one that leaves it η².
"""

from __future__ import annotations

from renderer.jit import kernel
from renderer.materials.fresnel import fresnel_dielectric, reflect, refract


@kernel
def dielectric_sample(param, wo, n, uc):
    """Returns (wi, weight): n is the outward normal of the closed shape."""
    ior = param[0]
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
