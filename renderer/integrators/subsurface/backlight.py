"""The seed lecture's backlight method: light from behind, through a thickness, into a lobe.

A ``translucent`` material with ``method: backlight`` is a Lambertian surface that reflects
(1 − scale) of its albedo (its BSDF, ``renderer.materials.bsdf``), plus a term for the direct
light that arrives from behind the surface: the light sample of the surface vertex
(``renderer.integrators.direct.surface_direct``) that the BSDF cannot see is passed here, and
what comes through is the transmitted share of that light, fading with the thickness of the
object the shadow ray crosses. Slots: ``renderer/materials/translucent.py``; the method:
docs/methods/backlight.md.
"""

from __future__ import annotations

import math

from renderer.geometry.bvh import intersect_closest
from renderer.geometry.shapes import spawn_offset, surface_point
from renderer.integrators.shadow import surface_shadow
from renderer.jit import block, kernel
from renderer.materials.translucent import ALBEDO, DISTORTION, POWER, SCALE, SIGMA_EFF


@kernel
def backlight_transmission(S, mp, p, n, wo, wi, t_max, stack):
    """The backlight method's transmitted fraction for light arriving from behind along −wi.

    After Barré-Brisebois & Bouchard (GDC 2011), as in the seed lecture: the thickness is measured
    by a ray from p into the object towards the light; the transmitted share
    scale·e^{−σ_eff·thickness} (σ_eff per channel, from the diffusion approximation: see
    renderer/materials/translucent.py) goes into a lobe about a = normalize(−wo − distortion·n)
    (the view direction seen through the object, bent by the normal),
    (power + 1)/(2π)·max(0, wi·a)^power. The lobe
    is normalized over the light directions, and the surface reflects only (1 − scale) of its
    albedo, so the method never returns more energy than arrives (the GDC formula is not
    normalized: it can).
    Light behind the object must still reach the far side: the rest of the way is a shadow ray.
    Returns the factors (per channel) that multiply albedo·Li (0 when nothing comes through).
    """
    ns = n
    if wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2] < 0.0:
        ns = (-n[0], -n[1], -n[2])
    if wi[0] * ns[0] + wi[1] * ns[1] + wi[2] * ns[2] >= 0.0:
        return 0.0, 0.0, 0.0
    ax = -wo[0] - mp[DISTORTION] * ns[0]
    ay = -wo[1] - mp[DISTORTION] * ns[1]
    az = -wo[2] - mp[DISTORTION] * ns[2]
    inv = 1.0 / math.sqrt(ax * ax + ay * ay + az * az)
    c = (wi[0] * ax + wi[1] * ay + wi[2] * az) * inv
    if c <= 0.0:
        return 0.0, 0.0, 0.0
    lobe = (mp[POWER] + 1.0) / (2.0 * math.pi) * c ** mp[POWER]
    # Thickness: from just inside p towards the light, to where the ray leaves the object
    inside = spawn_offset(p, ns, wi, max(abs(p[0]), abs(p[1]), abs(p[2])))
    t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                      S.prim_kind, S.prim_geo, inside, wi, t_max, stack)
    if prim < 0:
        return 0.0, 0.0, 0.0
    q, nq = surface_point(S.prim_kind[prim], S.prim_geo[prim], inside, wi, t, u, v)
    if surface_shadow(S, q, nq, wi, t_max - t, S.prim_scale[prim], -1, False, stack)[0] == 0.0:
        return 0.0, 0.0, 0.0
    k = mp[SCALE] * lobe
    return (k * math.exp(-mp[SIGMA_EFF] * t), k * math.exp(-mp[SIGMA_EFF + 1] * t),
            k * math.exp(-mp[SIGMA_EFF + 2] * t))


@block
def backlight_light(S, mp, p, n, wo, wi, li_rgb, pdf_l, t_max, br, bg, bb, stack):
    """β·albedo·Li·T/pdf: what the light sample (wi, Li, pdf) from behind the surface adds."""
    tr, tg, tb = backlight_transmission(S, mp, p, n, wo, wi, t_max, stack)
    return (br * mp[ALBEDO] * li_rgb[0] * tr / pdf_l, bg * mp[ALBEDO + 1] * li_rgb[1] * tg / pdf_l,
            bb * mp[ALBEDO + 2] * li_rgb[2] * tb / pdf_l)
