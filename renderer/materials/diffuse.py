"""Lambertian reflection. Parameters: ``albedo`` (RGB, 0..1) in ``param[0:3]``."""

from __future__ import annotations

import math

from renderer.jit import kernel
from renderer.sampling import cosine_hemisphere
from renderer.vecmath import to_world

INV_PI = 1.0 / math.pi


@kernel
def diffuse_eval(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return (0.0, 0.0, 0.0)
    s = cos_i * INV_PI
    return (param[0] * s, param[1] * s, param[2] * s)


@kernel
def diffuse_pdf(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    return cos_i * INV_PI if cos_i > 0.0 else 0.0


@kernel
def diffuse_sample(param, wo, n, u1, u2):
    local = cosine_hemisphere(u1, u2)
    wi = to_world(local, n)
    pdf = local[2] * INV_PI
    # f·cos/pdf = (ρ/π)·cos / (cos/π) = ρ
    return wi, (param[0], param[1], param[2]), pdf, local[2] > 0.0
