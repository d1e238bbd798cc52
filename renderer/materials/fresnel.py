"""Fresnel equations for a smooth dielectric interface, reflection and refraction directions."""

from __future__ import annotations

import math

from renderer.jit import kernel


@kernel
def fresnel_dielectric_sp(cos_i, eta):
    """Exact s- and p-polarized reflectances and cos θt for a smooth dielectric interface.

    ``cos_i`` ≥ 0 is the cosine of the incident angle on the incident side; ``eta`` = η_t/η_i,
    the relative index across the interface. Returns (Rs, Rp, cos_t); on total internal reflection
    (sin θt ≥ 1) both reflectances are 1 and cos_t is 0. Hecht, Optics (5th ed.), eqs. 4.42–4.43.
    """
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return r_s * r_s, r_p * r_p, cos_t


@kernel
def fresnel_dielectric(cos_i, eta):
    """Unpolarized reflectance: the mean of Rs and Rp (and cos θt)."""
    r_s, r_p, cos_t = fresnel_dielectric_sp(cos_i, eta)
    return 0.5 * (r_s + r_p), cos_t


@kernel
def reflect(wo, n):
    """Mirror ``wo`` (pointing away from the surface) about ``n``."""
    c = 2.0 * (wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2])
    return (c * n[0] - wo[0], c * n[1] - wo[1], c * n[2] - wo[2])


@kernel
def refract(wo, n, eta, cos_i, cos_t):
    """Snell refraction of ``wo`` (on the side of ``n``) into the other medium, η = η_t/η_i.

    wt = −wo/η + (cos θi/η − cos θt)·n, which is unit length when cos_t comes from Snell's law.
    """
    a = 1.0 / eta
    b = cos_i / eta - cos_t
    return (-wo[0] * a + b * n[0], -wo[1] * a + b * n[1], -wo[2] * a + b * n[2])
