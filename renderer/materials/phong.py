"""Normalized (energy-conserving) Phong: f = kd/π + ks·(n + 2)/(2π)·cosⁿα.

α is the angle between wi and the mirror direction of wo (Lafortune & Willems, "Using the
modified Phong reflectance model for physically based rendering", 1994). The (n + 2)/(2π) factor
makes the specular lobe's albedo at normal incidence exactly ks; with kd + ks ≤ 1 per channel (the
schema checks it) the surface never reflects more than it receives.

Row (``pack_phong``): ``diffuse`` kd in the three slots from ``KD``, ``specular`` ks in the three
from ``KS``, ``exponent`` n in ``EXPONENT``. Sampling picks a lobe with probability in proportion
to its luminance.
"""

from __future__ import annotations

import math

from renderer.jit import kernel
from renderer.materials.fresnel import reflect
from renderer.sampling import INV_PI, cosine_hemisphere, phong_lobe
from renderer.vecmath import Y_B, Y_G, Y_R, to_world

INV_2PI = 0.5 / math.pi

KD = 0
KS = 3
EXPONENT = 6


def pack_phong(p, m) -> None:
    """Write a ``phong`` material's row into ``p``."""
    p[KD:KD + 3] = m.diffuse
    p[KS:KS + 3] = m.specular
    p[EXPONENT] = m.exponent


@kernel
def _specular_probability(param):
    ld = Y_R * param[KD] + Y_G * param[KD + 1] + Y_B * param[KD + 2]
    ls = Y_R * param[KS] + Y_G * param[KS + 1] + Y_B * param[KS + 2]
    if ld + ls <= 0.0:
        return 0.0
    return ls / (ld + ls)


@kernel
def phong_eval(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return (0.0, 0.0, 0.0)
    r = reflect(wo, n)
    cos_a = r[0] * wi[0] + r[1] * wi[1] + r[2] * wi[2]
    exponent = param[EXPONENT]
    spec = (exponent + 2.0) * INV_2PI * cos_a**exponent if cos_a > 0.0 else 0.0
    return (
        (param[KD] * INV_PI + param[KS] * spec) * cos_i,
        (param[KD + 1] * INV_PI + param[KS + 1] * spec) * cos_i,
        (param[KD + 2] * INV_PI + param[KS + 2] * spec) * cos_i,
    )


@kernel
def phong_pdf(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return 0.0
    p_spec = _specular_probability(param)
    r = reflect(wo, n)
    cos_a = r[0] * wi[0] + r[1] * wi[1] + r[2] * wi[2]
    exponent = param[EXPONENT]
    pdf_spec = (exponent + 1.0) * INV_2PI * cos_a**exponent if cos_a > 0.0 else 0.0
    return (1.0 - p_spec) * cos_i * INV_PI + p_spec * pdf_spec


@kernel
def phong_sample(param, wo, n, uc, u1, u2):
    p_spec = _specular_probability(param)
    if uc < p_spec:
        wi = to_world(phong_lobe(u1, u2, param[EXPONENT]), reflect(wo, n))
    else:
        wi = to_world(cosine_hemisphere(u1, u2), n)
    pdf = phong_pdf(param, wo, wi, n)
    if pdf <= 0.0:
        # The specular lobe reached below the surface: no contribution from this sample.
        return wi, (0.0, 0.0, 0.0), 0.0, False
    f = phong_eval(param, wo, wi, n)
    return wi, (f[0] / pdf, f[1] / pdf, f[2] / pdf), pdf, True
