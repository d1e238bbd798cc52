"""The diffusion method: a separable BSSRDF, its exit point found by probe rays.

A ``translucent`` material with ``method: diffusion`` reflects F(θo) at its smooth coat (a rough
one: the GGX boundary's reflection, ``diffusion_exit``); the rest
of the light enters, travels under the surface by the Christensen–Burley profile S_p(r), and
leaves at an exit point found by a probe ray (``diffusion_probe``), through S_w, a diffuse-like
lobe (the ``DIFFUSION_EXIT`` BSDF). The model and its parameters (A, d, c):
``renderer/materials/diffusion.py``, which also packs the row; the method:
docs/methods/diffusion.md.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.geometry.bvh import intersect_closest
from renderer.geometry.shapes import spawn_offset, surface_point
from renderer.integrators.sampler import DIMS_PER_BOUNCE, draw
from renderer.jit import block, kernel
from renderer.materials.bsdf import DIFFUSION_EXIT, ROUGH_DIFFUSION
from renderer.materials.burley import (
    burley_pdf_area,
    burley_profile,
    burley_r_max,
    burley_sample_radius,
)
from renderer.materials.diffusion import MS_ALBEDO, OPAQUE, PROFILE_D
from renderer.materials.fresnel import fresnel_dielectric
from renderer.materials.rough_dielectric import rough_boundary_sample
from renderer.materials.translucent import IOR
from renderer.rng import mix64, uniform
from renderer.vecmath import onb


@kernel
def diffusion_probe(S, mat, p, n, mp, key, stack):
    """Find where light that entered at p leaves a ``diffusion`` material, by a probe ray.

    One of 9 strategies (axis: the normal with probability 1/2, each tangent 1/4; channel: 1/3
    each) picks a radius from that channel's Burley profile and an angle; a probe segment along
    the axis through that point finds the material's surfaces, and one of the k hits is chosen
    uniformly. The exit's weight is S_p(r)/pdf with pdf the sum over all 9 strategies of their
    densities at this point (one-sample MIS, balance heuristic). pbrt divides that density by k
    too, which counts the profile's energy once per surface the probe meets: in a part thinner
    than the profile (a shell, a slab of a few mean free paths) that returns up to k·A > 1 of the
    light. Lucent shares it among the k exits instead, so the model, made for a semi-infinite
    medium, darkens thin parts rather than creating energy (docs/methods/diffusion.md).
    Returns (ok, p_o, n_o, prim_o, weight rgb).
    """
    key2 = mix64(key ^ np.uint64(0xD1F5E))
    t_axis, b_axis = onb(n)
    u_axis = uniform(key2, 0)
    if u_axis < 0.5:
        axis, a1, a2 = n, t_axis, b_axis
    elif u_axis < 0.75:
        axis, a1, a2 = t_axis, b_axis, n
    else:
        axis, a1, a2 = b_axis, n, t_axis
    ch = min(2, int(3.0 * uniform(key2, 1)))
    d_ch = mp[PROFILE_D + ch]
    r = burley_sample_radius(uniform(key2, 2), d_ch)
    r_max = burley_r_max(d_ch, 0.999)
    none = (0.0, 0.0, 0.0)
    if not r < r_max:
        return False, p, n, -1, none
    phi = 2.0 * math.pi * uniform(key2, 3)
    half = math.sqrt(r_max * r_max - r * r)
    cx, sx = r * math.cos(phi), r * math.sin(phi)
    start = (p[0] + cx * a1[0] + sx * a2[0] + half * axis[0],
             p[1] + cx * a1[1] + sx * a2[1] + half * axis[1],
             p[2] + cx * a1[2] + sx * a2[2] + half * axis[2])
    dirn = (-axis[0], -axis[1], -axis[2])
    # Walk the segment, choosing one of the material's hits uniformly (reservoir sampling)
    k = 0
    chosen_p = p
    chosen_n = n
    chosen_prim = -1
    o = start
    remaining = 2.0 * half
    for _ in range(32):
        t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                          S.prim_kind, S.prim_geo, o, dirn,
                                          remaining, stack)
        if prim < 0:
            break
        q, nq = surface_point(S.prim_kind[prim], S.prim_geo[prim], o, dirn, t, u, v)
        if S.prim_material[prim] == mat:
            k += 1
            if uniform(key2, 3 + k) * k < 1.0:
                chosen_p, chosen_n, chosen_prim = q, nq, prim
        o2 = spawn_offset(q, nq, dirn, S.prim_scale[prim])
        remaining -= (o2[0] - o[0]) * dirn[0] + (o2[1] - o[1]) * dirn[1] + (o2[2] - o[2]) * dirn[2]
        o = o2
        if remaining <= 0.0:
            break
    if k == 0:
        return False, p, n, -1, none
    dx, dy, dz = chosen_p[0] - p[0], chosen_p[1] - p[1], chosen_p[2] - p[2]
    r2 = dx * dx + dy * dy + dz * dz
    pdf = 0.0
    for a in range(3):
        ax = n if a == 0 else (t_axis if a == 1 else b_axis)
        prob = 0.5 if a == 0 else 0.25
        along = dx * ax[0] + dy * ax[1] + dz * ax[2]
        r_proj = math.sqrt(max(0.0, r2 - along * along))
        cos_n = abs(chosen_n[0] * ax[0] + chosen_n[1] * ax[1] + chosen_n[2] * ax[2])
        for c in range(3):
            pdf += prob / 3.0 * burley_pdf_area(r_proj, mp[PROFILE_D + c]) * cos_n
    if not pdf > 0.0:
        return False, p, n, -1, none
    r_true = math.sqrt(r2)
    w = (mp[MS_ALBEDO] * burley_profile(r_true, mp[PROFILE_D]) / pdf,
         mp[MS_ALBEDO + 1] * burley_profile(r_true, mp[PROFILE_D + 1]) / pdf,
         mp[MS_ALBEDO + 2] * burley_profile(r_true, mp[PROFILE_D + 2]) / pdf)
    return True, chosen_p, chosen_n, chosen_prim, w


@block
def diffusion_exit(S, mat, mp, prim, p, n, wo, cos_o, scale, br, bg, bb, depth, max_depth, key,
                   dim, sidx, sob, stack):
    """The diffusion material ``mat`` (row ``mp``) hit from outside at p on ``prim``: where the
    path goes on from, and as what. The smooth coat reflects F of the light: with probability F
    (the same draw and Fresnel the boundary's ``bsdf_sample`` uses) the vertex stays as it is and
    the BSDF takes the mirror direction; the rest (1 − F, cancelled by its probability) goes
    under the surface and the path carries on from the exit vertex, lit through S_w. A rough
    coat (ROUGH_DIFFUSION) samples the GGX boundary instead (docs/methods/diffusion.md, "Rough
    coat"). Returns (ended, p, n, wo, kind, scale, br, bg, bb, depth, dim): ``dim`` the exit
    vertex's first dimension."""
    kind = S.mat_kind[mat]
    if kind == ROUGH_DIFFUSION:
        # The rough coat: one sample of the GGX boundary from the draws the vertex's own BSDF
        # sample takes, so that a reflection is the direction ``bsdf_sample`` returns next. What
        # refracts enters with the microfacet transmission's weight G1(wt), its radiance scaling
        # (η_i/η_t)² undone as at the smooth coat's entry (S_w's normalization covers the exit);
        # the exit vertex then draws from the next dimensions, apart from the coat's
        wi, w_c, _, ok_c = rough_boundary_sample(mp, wo, n, draw(S, key, dim, 3, sidx, sob),
                                                 draw(S, key, dim, 4, sidx, sob),
                                                 draw(S, key, dim, 5, sidx, sob))
        if not ok_c:
            return True, p, n, wo, kind, scale, br, bg, bb, depth, dim
        if wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0.0:
            return False, p, n, wo, kind, scale, br, bg, bb, depth, dim
        k = w_c[0] * mp[IOR] * mp[IOR]
        br *= k
        bg *= k
        bb *= k
        dim += DIMS_PER_BOUNCE
    else:
        f_o, _ = fresnel_dielectric(cos_o, mp[IOR])
        if not draw(S, key, dim, 3, sidx, sob) >= f_o:
            return False, p, n, wo, kind, scale, br, bg, bb, depth, dim
    if mp[OPAQUE] > 0.0:
        # Effectively opaque (auto, renderer/materials/opaque.py): the profile is narrower than a
        # pixel, so the light leaves where it entered, with probability A: the separable BSSRDF's
        # zero-radius limit, a BRDF
        ok, p_o, n_o, prim_o, w = True, p, n, prim, (mp[MS_ALBEDO], mp[MS_ALBEDO + 1],
                                                    mp[MS_ALBEDO + 2])
    else:
        ok, p_o, n_o, prim_o, w = diffusion_probe(S, mat, p, n, mp, key ^ np.uint64(dim), stack)
    if not ok:
        return True, p, n, wo, kind, scale, br, bg, bb, depth, dim
    br *= w[0]
    bg *= w[1]
    bb *= w[2]
    depth += 1
    ended = max_depth >= 0 and depth >= max_depth
    return ended, p_o, n_o, n_o, DIFFUSION_EXIT, S.prim_scale[prim_o], br, bg, bb, depth, dim
