"""Normalized (energy-conserving) Phong: f = kd/π + ks·(n + 2)/(2π)·cosⁿα.

α is the angle between wi and the mirror direction of wo (Lafortune & Willems, "Using the
modified Phong reflectance model for physically based rendering", 1994). The (n + 2)/(2π) factor
makes the specular lobe's albedo at normal incidence exactly ks; with kd + ks ≤ 1 per channel (the
schema checks it) the surface never reflects more than it receives.

Parameters: ``diffuse`` kd in ``param[0:3]``, ``specular`` ks in ``param[3:6]``, ``exponent`` n in
``param[6]``. Sampling picks a lobe with probability in proportion to its luminance.
"""

from __future__ import annotations

import math

from renderer.jit import kernel
from renderer.materials.fresnel import reflect
from renderer.sampling import cosine_hemisphere, phong_lobe
from renderer.vecmath import to_world

INV_PI = 1.0 / math.pi
INV_2PI = 0.5 / math.pi


@kernel
def _specular_probability(param):
    ld = 0.2126 * param[0] + 0.7152 * param[1] + 0.0722 * param[2]
    ls = 0.2126 * param[3] + 0.7152 * param[4] + 0.0722 * param[5]
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
    exponent = param[6]
    spec = (exponent + 2.0) * INV_2PI * cos_a**exponent if cos_a > 0.0 else 0.0
    return (
        (param[0] * INV_PI + param[3] * spec) * cos_i,
        (param[1] * INV_PI + param[4] * spec) * cos_i,
        (param[2] * INV_PI + param[5] * spec) * cos_i,
    )


@kernel
def phong_pdf(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return 0.0
    p_spec = _specular_probability(param)
    r = reflect(wo, n)
    cos_a = r[0] * wi[0] + r[1] * wi[1] + r[2] * wi[2]
    exponent = param[6]
    pdf_spec = (exponent + 1.0) * INV_2PI * cos_a**exponent if cos_a > 0.0 else 0.0
    return (1.0 - p_spec) * cos_i * INV_PI + p_spec * pdf_spec


@kernel
def phong_sample(param, wo, n, uc, u1, u2):
    p_spec = _specular_probability(param)
    if uc < p_spec:
        wi = to_world(phong_lobe(u1, u2, param[6]), reflect(wo, n))
    else:
        wi = to_world(cosine_hemisphere(u1, u2), n)
    pdf = phong_pdf(param, wo, wi, n)
    if pdf <= 0.0:
        # The specular lobe reached below the surface: no contribution from this sample.
        return wi, (0.0, 0.0, 0.0), 0.0, False
    f = phong_eval(param, wo, wi, n)
    return wi, (f[0] / pdf, f[1] / pdf, f[2] / pdf), pdf, True
