"""Shading normals: BSDFs asked about an interpolated normal without light leaking through the
surface or black pixels where the two normals disagree.

A mesh's ``normals`` bend shading only (scene format v1.1). The reflecting families (diffuse,
phong, mirror, conductor) and the smooth refracting boundaries (dielectric, translucent method
volumetric: ``_refracted_about``) are evaluated about the shading normal ns, with two guards:

- **Bending** (Keller et al. 2017, "The Iray Light Transport Simulation and Rendering System",
  the local adaption of shading normals): where the mirror direction of wo about ns would fall
  below the geometric surface (wo near the silhouette, or below ns's hemisphere, where a
  diffuse shading would go black), ns is turned towards the geometric normal until that mirror
  direction lies just above the surface, ns' = normalize(wo + r'). wo is then always in ns''s
  hemisphere, and a mirror or a smooth metal reflects into the scene, never through the surface.
- **Folding**: light arrives and leaves only above the geometric surface (no leaks, pbrt-v3's
  ``BSDF::f`` test of both directions against the geometric normal). A direction the lobe about
  ns would send below the surface is mirrored through the geometric tangent plane instead, so the
  folded lobe is f(wi) + f(R wi) (R: that mirror) with density p(wi) + p(R wi) above the surface.
  Nothing is lost: the folded lobe reflects what the lobe about ns reflects, its albedo, and a
  white diffuse surface under a uniform sky stays at 1 (the white furnace,
  tests/renderer/materials/test_shading.py), where dropping those directions (pbrt, Mitsuba)
  darkens a smooth-shaded object near its silhouette.

Evaluation, density and sampling agree (the sample is drawn about ns, folded, and weighed by the
folded value over the folded density), so next-event estimation and MIS stay unbiased. Where the
shading normal is the geometric one (flat triangles, every other primitive), each call is the
plain BSDF's, bit for bit.
"""

from __future__ import annotations

import math

from renderer.jit import inline_kernel, kernel
from renderer.materials.bsdf import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    PHONG,
    ROUGH_CONDUCTOR,
    TRANSLUCENT,
    bsdf_eval,
    bsdf_pdf,
    bsdf_sample,
)
from renderer.materials.dielectric import IOR

# How far above the geometric surface (the cosine) the mirror direction of wo about a bent
# shading normal is put: a direction this close to the tangent plane carries almost no light
BEND_EPSILON = 1e-3


@kernel
def uses_shading_normal(kind):
    """The families shaded about an interpolated normal: the reflecting ones, and the smooth
    refracting boundaries (glass; a translucent medium's, method volumetric), whose sampled
    direction is then checked against the geometric side (``_refracted_about``)."""
    return (kind == DIFFUSE or kind == PHONG or kind == MIRROR or kind == CONDUCTOR
            or kind == ROUGH_CONDUCTOR or kind == DIELECTRIC or kind == TRANSLUCENT)


@kernel
def _refracted_about(kind, param, wo, n, ns, uc, u1, u2):
    """A smooth refracting boundary's sample about the shading normal ns (on wo's side), with the
    geometric normal n deciding the sides: the Fresnel choice and the mirror or refracted
    direction come from ns (pbrt-v4's and Mitsuba's shading frame), but whether the path stays
    on wo's side or crosses, and so which medium it is in next, is the geometric surface's. A
    refraction about ns that stays above the geometric surface, or a reflection that would cross
    it, is mirrored through the geometric tangent plane (the fold of the reflecting families:
    the light neither leaks through the surface nor is lost), and its weight is that of what it
    does geometrically: 1 for staying, (η_i/η_t)² for crossing (the radiance scaling that
    belongs to a crossing, never to a reflection), so every event carries its energy whole and a
    furnace stays at 1."""
    nso = ns if _dot(ns, n) >= 0.0 else (-ns[0], -ns[1], -ns[2])  # outward, as the boundary's
    wi, weight, pdf, ok = bsdf_sample(kind, param, wo, nso, uc, u1, u2)
    cos_o = _dot(wo, n)
    stays_s = (_dot(wi, nso) > 0.0) == (_dot(wo, nso) > 0.0)
    stays_g = (_dot(wi, n) > 0.0) == (cos_o > 0.0)
    if stays_s != stays_g:
        wi = _fold(wi, n)
        stays_g = stays_s
    if stays_g:
        return wi, (1.0, 1.0, 1.0), pdf, ok
    eta = param[IOR] if cos_o > 0.0 else 1.0 / param[IOR]
    w = 1.0 / (eta * eta)
    return wi, (w, w, w), pdf, ok


@kernel
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def _fold(w, ng):
    """w mirrored through the plane of normal ng."""
    c = 2.0 * _dot(w, ng)
    return (w[0] - c * ng[0], w[1] - c * ng[1], w[2] - c * ng[2])


@kernel
def bent_normal(wo, ng, ns):
    """The shading normal ns (on ng's side) adapted for the view direction wo (Keller et al.
    2017): unchanged while wo's mirror direction about it stays BEND_EPSILON above the geometric
    surface; otherwise turned towards ng until it does. Returned on wo's side of the surface."""
    if _dot(wo, ng) < 0.0:
        ng = (-ng[0], -ng[1], -ng[2])
        ns = (-ns[0], -ns[1], -ns[2])
    c = _dot(wo, ns)
    r = (2.0 * c * ns[0] - wo[0], 2.0 * c * ns[1] - wo[1], 2.0 * c * ns[2] - wo[2])
    rn = _dot(r, ng)
    if rn >= BEND_EPSILON:
        return ns
    # r' : r's tangential direction, lifted to BEND_EPSILON above the surface
    tx, ty, tz = r[0] - rn * ng[0], r[1] - rn * ng[1], r[2] - rn * ng[2]
    t_len = math.sqrt(tx * tx + ty * ty + tz * tz)
    if not t_len > 1e-12:
        return ng
    s = math.sqrt(1.0 - BEND_EPSILON * BEND_EPSILON) / t_len
    rx = s * tx + BEND_EPSILON * ng[0]
    ry = s * ty + BEND_EPSILON * ng[1]
    rz = s * tz + BEND_EPSILON * ng[2]
    hx, hy, hz = wo[0] + rx, wo[1] + ry, wo[2] + rz
    h_len = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not h_len > 1e-12:
        return ng
    return (hx / h_len, hy / h_len, hz / h_len)


@kernel
def _same(a, b):
    return a[0] == b[0] and a[1] == b[1] and a[2] == b[2]


@inline_kernel
def shaded_eval(kind, param, wo, wi, n, ns):
    """f(wo, wi)·|cos θi| about the shading normal ns, folded above the geometric surface of
    normal n; ``bsdf_eval`` itself where ns is n."""
    if _same(ns, n):
        return bsdf_eval(kind, param, wo, wi, n)
    ng = n if _dot(wo, n) >= 0.0 else (-n[0], -n[1], -n[2])
    if _dot(wi, ng) <= 0.0:
        return (0.0, 0.0, 0.0)
    fr = fg = fb = 0.0
    w = wi
    for _ in range(2):
        f = bsdf_eval(kind, param, wo, w, ns)
        fr, fg, fb = fr + f[0], fg + f[1], fb + f[2]
        w = _fold(wi, ng)
    return (fr, fg, fb)


@inline_kernel
def shaded_pdf(kind, param, wo, wi, n, ns):
    """The density of ``shaded_sample`` (``bsdf_pdf`` where ns is n)."""
    if _same(ns, n):
        return bsdf_pdf(kind, param, wo, wi, n)
    ng = n if _dot(wo, n) >= 0.0 else (-n[0], -n[1], -n[2])
    if _dot(wi, ng) <= 0.0:
        return 0.0
    pdf = 0.0
    w = wi
    for _ in range(2):
        pdf += bsdf_pdf(kind, param, wo, w, ns)
        w = _fold(wi, ng)
    return pdf


@inline_kernel
def shaded_sample(kind, param, wo, n, ns, uc, u1, u2):
    """``bsdf_sample`` about the shading normal ns, the direction folded above the geometric
    surface of normal n: (wi, f·|cos|/pdf, pdf, ok), pdf 0 for a delta lobe."""
    if _same(ns, n):
        return bsdf_sample(kind, param, wo, n, uc, u1, u2)
    if kind == DIELECTRIC or kind == TRANSLUCENT:
        return _refracted_about(kind, param, wo, n, ns, uc, u1, u2)
    wi, weight, pdf, ok = bsdf_sample(kind, param, wo, ns, uc, u1, u2)
    ng = n if _dot(wo, n) >= 0.0 else (-n[0], -n[1], -n[2])
    if not ok:
        return wi, weight, pdf, ok
    if pdf == 0.0:  # a mirror about the bent normal: above the surface by construction
        return wi, weight, pdf, _dot(wi, ng) > 0.0
    if _dot(wi, ng) < 0.0:
        wi = _fold(wi, ng)
    pdf = shaded_pdf(kind, param, wo, wi, n, ns)
    if not pdf > 0.0:
        return wi, weight, pdf, False
    f = shaded_eval(kind, param, wo, wi, n, ns)
    return wi, (f[0] / pdf, f[1] / pdf, f[2] / pdf), pdf, True
