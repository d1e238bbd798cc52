"""The seed student project's diffuse_entry method: scatter at once on entry, then walk.

After Jeremiah Darais's "Subsurface Scattering" (the seed student project): a Fresnel coat at the
surface (the boundary's ``bsdf_sample``), and a ray that enters is scattered immediately, just
inside, about its refracted direction (g is the bias), multiplied by the colour; from there it is
the random walk of ``renderer/integrators/subsurface/volumetric.py``. Optional: a separate
direct-light estimate at the entry point (``direct_light``) and a glossy Phong coat instead of the
smooth one (``specular_exponent``). Slots: ``renderer/materials/translucent.py``; the method and
its bias: docs/methods/diffuse_entry.md.
"""

from __future__ import annotations

import math

from renderer.integrators.direct import light_sample
from renderer.integrators.sampler import draw
from renderer.integrators.shadow import surface_shadow_call
from renderer.jit import block
from renderer.materials.fresnel import fresnel_dielectric
from renderer.materials.phase import hg_sample
from renderer.materials.translucent import ALBEDO, DIRECT_LIGHT, IOR, SPECULAR_EXP, G
from renderer.sampling import phong_lobe
from renderer.vecmath import to_world


@block
def entry_direct(S, mp, p, n, cos_o, scale, null_media, br, bg, bb, key, dim, sidx, sob, stack):
    """β times the separate direct light at an entry point seen from outside: what enters here
    and comes back out is lit as a Lambertian surface of albedo (1 − F)·colour, from one light
    sample; the light the walk would carry straight out to a light is then not counted again
    (``entry_scatter``'s skip_emission)."""
    wi, li_rgb, pdf_l, t_max, delta_l = light_sample(S, p, key, dim, sidx, sob)
    cos_l = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
    if not (pdf_l > 0.0 and cos_l > 0.0):
        return 0.0, 0.0, 0.0
    tr = surface_shadow_call(S, p, n, wi, t_max, scale, -1, null_media, stack)
    if not (tr[0] > 0.0 or tr[1] > 0.0 or tr[2] > 0.0):
        return 0.0, 0.0, 0.0
    f_in, _ = fresnel_dielectric(cos_o, mp[IOR])
    q = math.pi * pdf_l
    return (br * mp[ALBEDO] * li_rgb[0] * (tr[0] * (1.0 - f_in) * cos_l / q),
            bg * mp[ALBEDO + 1] * li_rgb[1] * (tr[1] * (1.0 - f_in) * cos_l / q),
            bb * mp[ALBEDO + 2] * li_rgb[2] * (tr[2] * (1.0 - f_in) * cos_l / q))


@block
def entry_scatter(S, mp, n, cos_o, wi, weight, eta_scale, key, dim, sidx, sob):
    """The boundary's sample (wi, weight) at a diffuse_entry surface, turned into the method's:
    a ray that enters scatters at once about its refracted direction; a reflection off a glossy
    coat takes a Phong lobe about the mirror direction. Returns (ok, wi, weight, skip_emission,
    eta_scale): skip_emission when a ray leaves the object and its light at the next surface was
    counted by ``entry_direct``."""
    into = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0
    skip_emission = False
    if cos_o > 0.0 and into:
        ws, _ = hg_sample(wi, mp[G], draw(S, key, dim, 4, sidx, sob),
                          draw(S, key, dim, 5, sidx, sob))
        c = ws[0] * n[0] + ws[1] * n[1] + ws[2] * n[2]
        if c > 0.0:  # keep it inside: mirror it about the surface
            ws = (ws[0] - 2.0 * c * n[0], ws[1] - 2.0 * c * n[1], ws[2] - 2.0 * c * n[2])
        wi = ws
        weight = (weight[0] * mp[ALBEDO], weight[1] * mp[ALBEDO + 1], weight[2] * mp[ALBEDO + 2])
    elif cos_o > 0.0 and mp[SPECULAR_EXP] > 0.0:
        # Glossy coat: a normalized Phong lobe about the mirror direction, f·cos/pdf =
        # (n + 2)/(n + 1)·cos θi
        wg = to_world(phong_lobe(draw(S, key, dim, 4, sidx, sob), draw(S, key, dim, 5, sidx, sob),
                                 mp[SPECULAR_EXP]), wi)
        c = wg[0] * n[0] + wg[1] * n[1] + wg[2] * n[2]
        if c <= 0.0:
            return False, wi, weight, skip_emission, eta_scale
        wi = wg
        k = (mp[SPECULAR_EXP] + 2.0) / (mp[SPECULAR_EXP] + 1.0) * c
        weight = (k, k, k)
    elif cos_o < 0.0 and not into and mp[DIRECT_LIGHT] > 0.0:
        skip_emission = True
    if (cos_o > 0.0) != (wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0.0):
        # Refracted in or out: the η² of the radiance scaling, undone for roulette
        eta_scale *= mp[IOR] * mp[IOR] if cos_o > 0.0 else 1.0 / (mp[IOR] * mp[IOR])
    return True, wi, weight, skip_emission, eta_scale
