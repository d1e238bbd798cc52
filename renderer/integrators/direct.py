"""Next-event estimation: one light sample at a vertex, its shadow ray, its MIS weight.

At every vertex that can take one (pbrt-v4's PathIntegrator::SampleLd), a light is chosen and a
point on it sampled (``renderer.lights``), the shadow ray asked what reaches the vertex
(``renderer.integrators.shadow``), and the estimate weighted by Veach's power heuristic against
the chance that the vertex's own scattering sample finds the same light; delta lights (point,
directional) take the light sample alone. ``surface_direct`` serves a surface vertex (the BSDF,
or the backlight method's transmitted term for light from behind), ``medium_direct`` a
scattering event inside a medium (the phase function). Each returns β times what the sample
adds; the caller adds it to the path's radiance.
"""

from __future__ import annotations

import math

from renderer.integrators.sampler import draw
from renderer.integrators.shadow import SHADOW_SLACK, surface_shadow, transmittance
from renderer.integrators.subsurface.backlight import backlight_light
from renderer.jit import block
from renderer.lights import sample_light
from renderer.materials.bsdf import BACKLIGHT, rough_boundary
from renderer.materials.phase import hg_pdf
from renderer.materials.shading import shaded_eval, shaded_pdf
from renderer.sampling import power_heuristic


@block
def light_sample(S, p, key, dim, sidx, sob):
    """One sample of the scene's lights seen from p, from the vertex's light dimensions (0–2):
    (wi, Li, pdf, distance to the light point, delta)."""
    return sample_light(S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf,
                        S.prim_kind, S.prim_geo, S.env_image, S.env_marginal, S.env_conditional,
                        S.env_rotation, p, draw(S, key, dim, 0, sidx, sob),
                        draw(S, key, dim, 1, sidx, sob), draw(S, key, dim, 2, sidx, sob))


@block
def surface_direct(S, mk, mp, p, n, ns, wo, scale, medium, null_media, br, bg, bb, key, dim,
                   sidx, sob, stack):
    """β·f·Li·Tr/pdf of one light sample at a surface vertex of material kind ``mk`` (row
    ``mp``, geometric normal n, shading normal ns: ``renderer.materials.shading``),
    MIS-weighted against the BSDF; ``medium`` is the material of the medium on the side
    the shadow ray starts (−1: vacuum); for a rough translucent boundary, the boundary's own
    medium, which the shadow ray is in when it goes inside."""
    none = (0.0, 0.0, 0.0)
    wi, li_rgb, pdf_l, t_max, delta_l = light_sample(S, p, key, dim, sidx, sob)
    if not pdf_l > 0.0:
        return none
    f = shaded_eval(mk, mp, wo, wi, n, ns)
    if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
        if rough_boundary(mk):
            # ``medium`` is the boundary's own: the shadow ray starts in it when wi goes inside
            # (a light within the object), else in vacuum; through the medium it is attenuated
            inside = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0
            tr = surface_shadow(S, p, n, wi, t_max, scale, medium if inside else -1,
                                null_media or inside, stack)
        else:
            tr = surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack)
        if not (tr[0] > 0.0 or tr[1] > 0.0 or tr[2] > 0.0):
            return none
        wr, wg, wb = tr[0] / pdf_l, tr[1] / pdf_l, tr[2] / pdf_l
        if not delta_l:
            mis = power_heuristic(pdf_l, shaded_pdf(mk, mp, wo, wi, n, ns))
            wr, wg, wb = wr * mis, wg * mis, wb * mis
        return br * f[0] * li_rgb[0] * wr, bg * f[1] * li_rgb[1] * wg, bb * f[2] * li_rgb[2] * wb
    if mk == BACKLIGHT:
        # The light is behind the surface: the backlight approximation's term
        return backlight_light(S, mp, p, n, wo, wi, li_rgb, pdf_l, t_max, br, bg, bb, stack)
    return none


@block
def medium_direct(S, p, d, g, medium, br, bg, bb, key, dim, sidx, sob, stack):
    """β·phase·Li·Tr/pdf of one light sample at a scattering event at p inside ``medium`` (ray
    direction d before the event, Henyey–Greenstein asymmetry g), MIS-weighted against the phase
    function's sample. Only from a medium a shadow ray can leave: behind an index-matched or
    single-scatter boundary (a refracting boundary is a delta BSDF no light sample can cross)."""
    wi, li_rgb, pdf_l, t_max, delta_l = light_sample(S, p, key, dim, sidx, sob)
    if not pdf_l > 0.0:
        return 0.0, 0.0, 0.0
    if t_max < math.inf:
        t_max *= 1.0 - SHADOW_SLACK
    tr = transmittance(S, p, wi, t_max, medium, stack)
    if not (tr[0] > 0.0 or tr[1] > 0.0 or tr[2] > 0.0):
        return 0.0, 0.0, 0.0
    ph = hg_pdf(d[0] * wi[0] + d[1] * wi[1] + d[2] * wi[2], g)
    wr, wg, wb = tr[0] * ph / pdf_l, tr[1] * ph / pdf_l, tr[2] * ph / pdf_l
    if not delta_l:
        mis = power_heuristic(pdf_l, ph)
        wr, wg, wb = wr * mis, wg * mis, wb * mis
    return br * li_rgb[0] * wr, bg * li_rgb[1] * wg, bb * li_rgb[2] * wb
