"""Conductors (metals): smooth, or rough by the GGX microfacet model, with the exact Fresnel term.

A metal reflects a share F(θ) of the light that depends on its complex index of refraction
η + ik per channel: the unpolarized mean of the s- and p-polarized reflectances of the Fresnel
equations with a complex refractive index (Born & Wolf, Principles of Optics, §14.2; pbrt-v4's
FrComplex), times an optional ``specular`` scale. Row (``pack_conductor``): ``ETA`` and ``K``
(three slots each), ``SPECULAR`` (three) and ``ALPHA``. ``preset`` names measured metals: their η
and k at 650, 550 and 450 nm (``CONDUCTOR_PRESETS``).

A rough metal (``roughness`` α > 0) is the GGX (Trowbridge–Reitz) microfacet BRDF
f = F(wo·h) D(h) G(wo, wi) / (4 cos θo cos θi), with Smith's masking in its separable form
G = G1(wo) G1(wi), as Mitsuba 3's ``roughconductor`` computes it (pbrt-v4 takes the
height-correlated form), sampled by its visible normals (Heitz, "Sampling the GGX Distribution of
Visible Normals", JCGT 2018): pdf(wi) = G1(wo) D(h) / (4 cos θo), so a sample weighs
F·G1(wi).
"""

from __future__ import annotations

import cmath
import math

from renderer.jit import kernel
from renderer.materials.fresnel import reflect
from renderer.materials.microfacet import from_local, ggx_d, ggx_visible_normal, smith_g1, to_local
from renderer.vecmath import onb

ETA = 0
K = 3
SPECULAR = 6
ALPHA = 9

# η and k of measured metals at 650 nm (R), 550 nm (G) and 450 nm (B), from the data of
# refractiveindex.info (gold, silver, copper: Johnson & Christy 1972; aluminium: Rakić 1995) as
# tabulated in Chaos Group's "Understanding metalness" (the same RGB table Hindefjord gives)
CONDUCTOR_PRESETS = {
    "Au": ((0.18299, 0.42108, 1.3734), (3.4242, 2.3459, 1.7704)),
    "Ag": ((0.15943, 0.14512, 0.13547), (3.9291, 3.1900, 2.3808)),
    "Cu": ((0.27105, 0.67693, 1.3164), (3.6092, 2.6248, 2.2921)),
    "Al": ((1.3456, 0.96521, 0.61722), (7.4746, 6.3995, 5.3031)),
}


def pack_conductor(p, m) -> None:
    """Write a ``conductor`` material's row into ``p``."""
    eta, k = CONDUCTOR_PRESETS[m.preset] if m.preset is not None else (m.eta, m.k)
    p[ETA:ETA + 3] = eta
    p[K:K + 3] = k
    p[SPECULAR:SPECULAR + 3] = m.specular
    p[ALPHA] = m.roughness


@kernel
def fresnel_conductor(cos_i, eta, k):
    """Unpolarized reflectance of a smooth conductor of complex index η + ik, seen from a
    dielectric of index 1 at incidence cos θi ∈ [0, 1]."""
    cos_i = min(max(cos_i, 0.0), 1.0)
    n = complex(eta, k)
    sin2_t = (1.0 - cos_i * cos_i) / (n * n)
    cos_t = cmath.sqrt(1.0 - sin2_t)
    r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (abs(r_s) ** 2 + abs(r_p) ** 2)


@kernel
def conductor_sample(param, wo, n):
    """(wi, weight): the mirror direction, weighted by F(θ)·specular per channel (n faces wo)."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    return reflect(wo, n), (
        param[SPECULAR] * fresnel_conductor(cos_o, param[ETA], param[K]),
        param[SPECULAR + 1] * fresnel_conductor(cos_o, param[ETA + 1], param[K + 1]),
        param[SPECULAR + 2] * fresnel_conductor(cos_o, param[ETA + 2], param[K + 2]),
    )


@kernel
def rough_conductor_eval(param, wo, wi, n):
    """f(wo, wi)·cos θi of the rough metal (n faces wo; zero below the surface)."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_o <= 0.0 or cos_i <= 0.0:
        return (0.0, 0.0, 0.0)
    hx, hy, hz = wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    alpha = param[ALPHA]
    d = ggx_d(hx * n[0] + hy * n[1] + hz * n[2], alpha)
    g = smith_g1(cos_o, alpha) * smith_g1(cos_i, alpha)
    k = d * g / (4.0 * cos_o)
    c = wo[0] * hx + wo[1] * hy + wo[2] * hz
    return (param[SPECULAR] * fresnel_conductor(c, param[ETA], param[K]) * k,
            param[SPECULAR + 1] * fresnel_conductor(c, param[ETA + 1], param[K + 1]) * k,
            param[SPECULAR + 2] * fresnel_conductor(c, param[ETA + 2], param[K + 2]) * k)


@kernel
def rough_conductor_pdf(param, wo, wi, n):
    """The density of ``rough_conductor_sample``'s wi: G1(wo) D(h) / (4 cos θo)."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_o <= 0.0 or cos_i <= 0.0:
        return 0.0
    hx, hy, hz = wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    alpha = param[ALPHA]
    d = ggx_d((hx * n[0] + hy * n[1] + hz * n[2]) * inv, alpha)
    return smith_g1(cos_o, alpha) * d / (4.0 * cos_o)


@kernel
def rough_conductor_sample(param, wo, n, u1, u2):
    """(wi, f·cos/pdf, pdf, ok): a visible microfacet normal, wo reflected about it."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    none = (0.0, 0.0, 0.0)
    if cos_o <= 0.0:
        return n, none, 0.0, False
    t, b = onb(n)
    h = from_local(ggx_visible_normal(to_local(wo, t, b, n), param[ALPHA], u1, u2), t, b, n)
    wi = reflect(wo, h)
    cos_i = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if cos_i <= 0.0:
        return wi, none, 0.0, False
    pdf = rough_conductor_pdf(param, wo, wi, n)
    if not pdf > 0.0:
        return wi, none, 0.0, False
    g1 = smith_g1(cos_i, param[ALPHA])
    c = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2]
    weight = (param[SPECULAR] * fresnel_conductor(c, param[ETA], param[K]) * g1,
              param[SPECULAR + 1] * fresnel_conductor(c, param[ETA + 1], param[K + 1]) * g1,
              param[SPECULAR + 2] * fresnel_conductor(c, param[ETA + 2], param[K + 2]) * g1)
    return wi, weight, pdf, True

