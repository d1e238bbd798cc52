"""Rough dielectric: GGX microfacets that reflect and refract (Walter et al., "Microfacet Models
for Refraction through Rough Surfaces", EGSR 2007), as Mitsuba 3's ``roughdielectric``.

The row is the dielectric's (``renderer/materials/dielectric.py``) with the GGX α in its
``ROUGHNESS`` slot. For wo and wi on one side the BSDF reflects, f = F D G / (4 |cos θo cos θi|)
with h the half vector; on opposite sides it refracts through the microfacet h ∝ η·wi + wo
(η the index of wi's side over wo's), f = (1 − F) D G |wi·h wo·h| / (|cos θi cos θo|
(wi·h + wo·h/η)²), divided by η² for radiance (the smooth dielectric's (η_i/η_t)²). F is the
exact dielectric Fresnel term at wo·h; G = G1(wo) G1(wi) (separable, Mitsuba's). Sampling: a
visible normal from wo (``renderer.materials.microfacet``), then reflection with probability F,
else refraction; its density is what ``rough_dielectric_pdf`` returns and MIS uses.

The same boundary over a scattering medium is the ``translucent`` material's with ``roughness``
(method volumetric): ``rough_boundary_*``, the kind ``ROUGH_TRANSLUCENT``; as Mitsuba 3's
``roughdielectric`` on the boundary of a ``homogeneous`` medium.
"""

from __future__ import annotations

import math

from renderer.jit import kernel
from renderer.materials.dielectric import IOR, ROUGHNESS
from renderer.materials.fresnel import fresnel_dielectric, reflect, refract
from renderer.materials.microfacet import from_local, ggx_d, ggx_visible_normal, smith_g1, to_local
from renderer.materials.translucent import BOUNDARY_ROUGHNESS
from renderer.vecmath import onb


@kernel
def _terms(ior, alpha, wo, wi, n):
    """(value f·|cos θi|, pdf) of the rough boundary of index ``ior`` and GGX ``alpha`` for
    (wo, wi); n the outward normal."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_o == 0.0 or cos_i == 0.0:
        return 0.0, 0.0
    reflecting = cos_o * cos_i > 0.0
    etap = 1.0
    if not reflecting:
        etap = ior if cos_o > 0.0 else 1.0 / ior
    mx, my, mz = wi[0] * etap + wo[0], wi[1] * etap + wo[1], wi[2] * etap + wo[2]
    length = math.sqrt(mx * mx + my * my + mz * mz)
    if not length > 0.0:
        return 0.0, 0.0
    mx, my, mz = mx / length, my / length, mz / length
    if mx * n[0] + my * n[1] + mz * n[2] < 0.0:
        mx, my, mz = -mx, -my, -mz
    wo_m = wo[0] * mx + wo[1] * my + wo[2] * mz
    wi_m = wi[0] * mx + wi[1] * my + wi[2] * mz
    if wi_m * cos_i <= 0.0 or wo_m * cos_o <= 0.0:  # a backfacing microfacet
        return 0.0, 0.0
    f, _ = fresnel_dielectric(abs(wo_m), ior if cos_o > 0.0 else 1.0 / ior)
    d = ggx_d(mx * n[0] + my * n[1] + mz * n[2], alpha)
    g1_o = smith_g1(abs(cos_o), alpha)
    g = g1_o * smith_g1(abs(cos_i), alpha)
    visible = g1_o * abs(wo_m) * d / abs(cos_o)  # the visible normals' density of h
    if reflecting:
        return f * d * g / (4.0 * abs(cos_o)), visible / (4.0 * abs(wo_m)) * f
    denom = wi_m + wo_m / etap
    denom *= denom
    value = (1.0 - f) * d * g * abs(wi_m * wo_m) / (abs(cos_o) * denom) / (etap * etap)
    return value, visible * abs(wi_m) / denom * (1.0 - f)


@kernel
def _sample(ior, alpha, wo, n, uc, u1, u2):
    """(wi, f·cos/pdf, pdf, ok): a visible microfacet normal of wo's side, then reflection with
    probability F, else refraction through it."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    none = (0.0, 0.0, 0.0)
    if cos_o == 0.0:
        return n, none, 0.0, False
    ns = n if cos_o > 0.0 else (-n[0], -n[1], -n[2])
    eta = ior if cos_o > 0.0 else 1.0 / ior
    t, b = onb(ns)
    h = from_local(ggx_visible_normal(to_local(wo, t, b, ns), alpha, u1, u2), t, b, ns)
    wo_h = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2]
    if not wo_h > 0.0:
        return n, none, 0.0, False
    f, cos_t = fresnel_dielectric(wo_h, eta)
    reflecting = uc < f
    if reflecting:
        wi = reflect(wo, h)
    else:
        wi = refract(wo, h, eta, wo_h, cos_t)
    # A reflection about h that points below the surface (or a refraction that stays above it)
    # is no sample: (wo, wi) would name another microfacet, with another density
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if (cos_o * cos_i > 0.0) != reflecting:
        return wi, none, 0.0, False
    value, pdf = _terms(ior, alpha, wo, wi, n)
    if not pdf > 0.0:
        return wi, none, 0.0, False
    w = value / pdf
    return wi, (w, w, w), pdf, True


# The rough dielectric's row keeps α in dielectric's ROUGHNESS slot; a rough translucent
# boundary (method volumetric) in translucent's BOUNDARY_ROUGHNESS, since its slot 4 is DENSITY.
@kernel
def rough_dielectric_eval(param, wo, wi, n):
    v, _ = _terms(param[IOR], param[ROUGHNESS], wo, wi, n)
    return (v, v, v)


@kernel
def rough_dielectric_pdf(param, wo, wi, n):
    _, pdf = _terms(param[IOR], param[ROUGHNESS], wo, wi, n)
    return pdf


@kernel
def rough_dielectric_sample(param, wo, n, uc, u1, u2):
    return _sample(param[IOR], param[ROUGHNESS], wo, n, uc, u1, u2)


@kernel
def rough_boundary_eval(param, wo, wi, n):
    v, _ = _terms(param[IOR], param[BOUNDARY_ROUGHNESS], wo, wi, n)
    return (v, v, v)


@kernel
def rough_boundary_pdf(param, wo, wi, n):
    _, pdf = _terms(param[IOR], param[BOUNDARY_ROUGHNESS], wo, wi, n)
    return pdf


@kernel
def rough_boundary_sample(param, wo, n, uc, u1, u2):
    return _sample(param[IOR], param[BOUNDARY_ROUGHNESS], wo, n, uc, u1, u2)
