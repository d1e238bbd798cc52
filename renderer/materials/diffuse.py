"""Lambertian reflection.

Row: ``ALBEDO`` (RGB, 0..1) in ``param[ALBEDO:ALBEDO + 3]``; ``pack_diffuse`` writes it. Other
families with a Lambertian lobe pass their row sliced so that their colour starts at ``ALBEDO``.
"""

from __future__ import annotations

from renderer.jit import kernel
from renderer.sampling import INV_PI, cosine_hemisphere
from renderer.vecmath import to_world

ALBEDO = 0


def pack_diffuse(p, m) -> None:
    """Write a ``diffuse`` material's row into ``p``."""
    p[ALBEDO:ALBEDO + 3] = m.albedo


@kernel
def diffuse_eval(param, wo, wi, n):
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return (0.0, 0.0, 0.0)
    s = cos_i * INV_PI
    return (param[ALBEDO] * s, param[ALBEDO + 1] * s, param[ALBEDO + 2] * s)


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
    return wi, (param[ALBEDO], param[ALBEDO + 1], param[ALBEDO + 2]), pdf, local[2] > 0.0
