"""Unidirectional path tracing with next-event estimation and multiple importance sampling.

The structure is pbrt-v4's PathIntegrator::Li. At every non-delta vertex one light sample
(``renderer.lights``) and one BSDF sample are taken; where both strategies can reach the same
light (area lights and the background), each is weighted by Veach's power heuristic, and delta
lights (point, directional) take the light sample alone. Paths are ended by Russian roulette from
``RR_DEPTH`` scattering events on, with survival probability min(max(β)·Πη², 0.95) at surfaces as
in Mitsuba 3 (the η² undoes the radiance scaling of refraction) and min(max(β)·Πη², 1) at medium
events (pbrt-v4's rule, so long walks in high-albedo media are not cut short), so an unlimited
``max_depth`` (-1) stays unbiased.

``max_depth`` counts scattering events (scene format v1): 0 shows only what the camera sees
directly, 1 adds direct lighting. Mitsuba's ``max_depth`` counts path segments, one more.

Translucent materials with ``method: volumetric`` are homogeneous media behind a dielectric (or,
at ior 1, index-matched) boundary: inside, free flights are sampled from exp(−σt·s) with the grey
σt = density, each scattering event weights the path by the albedo and samples the
Henyey–Greenstein phase function (Mitsuba 3's volpath, analogue sampling). Behind an
index-matched boundary, scattering events also take a light sample, whose shadow ray carries the
medium's transmittance; behind a refracting boundary they cannot (the boundary is a delta BSDF).

Random numbers: dimensions 0 and 1 jitter the pixel; each path segment then uses the
``DIMS_PER_BOUNCE`` dimensions that follow, always the same ones for the same role (0–2 light
sample, 3–5 BSDF or phase sample, 6 roulette, 7 free flight), so one sample's path is a pure
function of (seed, pixel, sample index) — see ``renderer.rng``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from renderer.geometry.bvh import intersect_closest, occluded, traversal_stack
from renderer.geometry.flat import flat_planar_t
from renderer.geometry.shapes import (
    SPAWN_EPSILON,
    SPHERE,
    spawn_offset,
    sphere_roots,
    surface_point,
)
from renderer.jit import inline_kernel, kernel, parallel_kernel
from renderer.lights import area_light_pdf, sample_light
from renderer.materials.bsdf import (
    BACKLIGHT,
    DIELECTRIC,
    DIFFUSE_ENTRY,
    DIFFUSION,
    DIFFUSION_EXIT,
    SINGLE_SCATTER,
    TRANSLUCENT,
    bsdf_eval,
    bsdf_pdf,
    bsdf_sample,
    is_delta,
)
from renderer.materials.burley import (
    burley_pdf_area,
    burley_profile,
    burley_r_max,
    burley_sample_radius,
)
from renderer.materials.fresnel import fresnel_dielectric
from renderer.materials.phase import hg_pdf, hg_sample
from renderer.rng import mix64, sample_key, sobol_block_seeds, sobol_value, uniform
from renderer.sampling import INV_4PI, phong_lobe, power_heuristic
from renderer.vecmath import onb, to_world

RR_DEPTH = 5
RR_MAX = 0.95  # at surfaces; inside media the survival probability is not capped (see there)
DIMS_PER_BOUNCE = 8
PIXEL_SEED_SALT = np.uint64(0x5D1E5EEDC0FFEE11)
SOBOL_VERTICES = 2  # vertices whose samples the sobol sampler stratifies
SOBOL_BLOCKS = 1 + 5 * SOBOL_VERTICES  # its sequences: the camera's, then five a vertex (draw)
# A guard against a path that never ends (a ray trapped between two perfect mirrors with
# roulette surviving at 0.95 still ends, but only with probability one). Every scattering event
# past RR_DEPTH survives with probability ≤ 0.95, so a path of 2¹⁸ segments (scattering events
# and index-matched boundary crossings) has probability ~10⁻¹⁰⁰⁰: the cap never biases an image.
MAX_SEGMENTS = 1 << 18
# A shadow ray stops this fraction of its length (plus SPAWN_EPSILON of the light point's
# coordinates) short of the light point it aims at, so it does not hit the light's own surface;
# sampled points are exact to ~1e-15 relative.
SHADOW_SLACK = 1e-7


@kernel
def roulette(br, bg, bb, eta_scale, cap, u):
    """Russian roulette: survive with q = min(max(β)·Πη², cap), then β/q. Returns (alive, β)."""
    q = min(max(br, bg, bb) * eta_scale, cap)
    if u >= q:
        return False, br, bg, bb
    return True, br / q, bg / q, bb / q


@inline_kernel
def shadow_passable(S, mat):
    """A shadow ray may cross a surface of material ``mat``: an index-matched translucent medium's
    boundary or a single-scatter object's (see transmittance)."""
    kind = S.mat_kind[mat]
    return (kind == TRANSLUCENT and S.mat_param[mat, 0] == 1.0) or kind == SINGLE_SCATTER


@inline_kernel
def transmittance(S, o, d, t_max, medium, stack):
    """Fraction of light that travels from o to o + t_max·d: 0 when a surface blocks it, else
    exp(−σt·length) over the stretches inside index-matched translucent media (their boundaries
    neither reflect nor refract, so a shadow ray may cross them) and single-scatter objects (whose
    surface lets 1 − surface_fraction of the light in, straight on). ``medium`` is the material of
    the medium at o (−1: vacuum).

    A flat scene takes every crossing from one pass (flat_transmittance); in a tree the ray is
    traced on from each surface it crosses (transmittance_by_crossing)."""
    if S.flat.shape[1] > 0:
        return flat_transmittance(S, o, d, t_max, medium, stack[2])
    return transmittance_by_crossing(S, o, d, t_max, medium, stack)


@kernel
def transmittance_by_crossing(S, o, d, t_max, medium, stack):
    """``transmittance`` by a closest-hit query from each surface crossed to the next.

    A call, not inlined: it serves the scenes searched with a tree, where the tree walk for each
    crossing outweighs the call. Inlined in numba's IR, its copies at three sites in
    ``trace_path`` cost compile time; inlined by LLVM, the renders were no faster
    (docs/performance.md, "Start-up", "Inlined by LLVM")."""
    tr = 1.0
    for _ in range(64):
        t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                          S.prim_kind, S.prim_geo, o, d, t_max, stack)
        if medium >= 0:
            tr *= math.exp(-S.mat_param[medium, 4] * min(t, t_max))
        if prim < 0:
            return tr
        mat = S.prim_material[prim]
        kind = S.mat_kind[mat]
        if not shadow_passable(S, mat) or tr == 0.0:
            return 0.0
        p, n = surface_point(S.prim_kind[prim], S.prim_geo[prim], o, d, t, u, v)
        entering = d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < 0.0
        if entering and kind == SINGLE_SCATTER:
            tr *= 1.0 - S.mat_param[mat, 7]
        medium = mat if entering else -1
        o2 = spawn_offset(p, n, d, S.prim_scale[prim])
        t_max -= (o2[0] - o[0]) * d[0] + (o2[1] - o[1]) * d[1] + (o2[2] - o[2]) * d[2]
        o = o2
    return 0.0


@inline_kernel
def crossing(S, mat, t, entering, tau, open_sigma, n_open, tr):
    """One crossing of ``flat_transmittance``'s sum: (tau, open_sigma, n_open, tr) after it."""
    sigma = S.mat_param[mat, 4]
    if entering:
        if S.mat_kind[mat] == SINGLE_SCATTER:
            tr *= 1.0 - S.mat_param[mat, 7]
        return tau - sigma * t, open_sigma + sigma, n_open + 1, tr
    return tau + sigma * t, open_sigma - sigma, n_open - 1, tr


@inline_kernel
def flat_transmittance(S, o, d, t_max, medium, out):
    """``transmittance`` in a flat scene, from one pass over all its primitives.

    Every primitive the ray meets before t_max is a crossing (any other surface blocks: 0); a
    sphere (they come first in a flat scene) is met at both its roots, entering at the nearer.
    The optical depth is summed over the crossings in any order: leaving a medium of σt at t adds
    σt·t, entering one takes σt·t off, and the media still open at the end (entered, or the one
    at o, and not left) add their σt·t_max; what remains is σt times the length inside each
    medium. That is the crossing-by-crossing loop's answer for media that do not overlap (each
    closed object's boundary entered and left in turn), up to rounding; a shadow ray to a light
    at infinity (t_max = inf) that leaves every medium it entered has a finite depth. ``out`` is
    (3, FLAT_MAX) scratch."""
    tau = 0.0
    open_sigma = S.mat_param[medium, 4] if medium >= 0 else 0.0
    n_open = 1 if medium >= 0 else 0
    tr = 1.0
    k = 0
    while k < S.prim_kind.shape[0] and S.prim_kind[k] == SPHERE:
        t0, t1 = sphere_roots(o, d, S.prim_geo[k])
        enters = 0.0 < t0 < t_max
        leaves = 0.0 < t1 < t_max
        if enters or leaves:
            mat = S.prim_material[k]
            if not shadow_passable(S, mat):
                return 0.0
            if enters:
                tau, open_sigma, n_open, tr = crossing(S, mat, t0, True, tau, open_sigma,
                                                       n_open, tr)
            if leaves:
                tau, open_sigma, n_open, tr = crossing(S, mat, t1, False, tau, open_sigma,
                                                       n_open, tr)
        k += 1
    flat_planar_t(S.flat, o, d, out)
    for k in range(min(S.flat.shape[1], out.shape[1])):
        t = out[0, k]
        if t < t_max:
            mat = S.prim_material[k]
            if not shadow_passable(S, mat):
                return 0.0
            g = S.prim_geo[k]
            # d·(e1 × e2): the sign that tells entering (< 0) from leaving, as surface_point's
            # outward normal does
            dn = (d[0] * (g[4] * g[8] - g[5] * g[7]) + d[1] * (g[5] * g[6] - g[3] * g[8])
                  + d[2] * (g[3] * g[7] - g[4] * g[6]))
            tau, open_sigma, n_open, tr = crossing(S, mat, t, dn < 0.0, tau, open_sigma,
                                                   n_open, tr)
    if n_open > 0:
        tau += open_sigma * t_max
    return tr * math.exp(-max(tau, 0.0))


@inline_kernel
def surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack):
    """Transmittance of the shadow ray from surface point p towards a light t_max away along wi.

    The ray starts lifted off the surface (``spawn_offset``); its length is measured from there,
    and it stops short of the light's own surface by more than the rounding of the light point
    (SHADOW_SLACK of the length plus SPAWN_EPSILON of its coordinates), so neither surface can
    shadow itself at any scene scale. Plain occlusion unless the scene has surfaces a shadow ray
    may cross (``null_media``).
    """
    origin = spawn_offset(p, n, wi, scale)
    if t_max < math.inf:
        q = (p[0] + t_max * wi[0], p[1] + t_max * wi[1], p[2] + t_max * wi[2])
        t_max -= ((origin[0] - p[0]) * wi[0] + (origin[1] - p[1]) * wi[1]
                  + (origin[2] - p[2]) * wi[2])
        t_max = t_max * (1.0 - SHADOW_SLACK) - SPAWN_EPSILON * max(abs(q[0]), abs(q[1]),
                                                                  abs(q[2]))
    if null_media:
        return transmittance(S, origin, wi, t_max, medium, stack)
    if occluded(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat, S.prim_kind, S.prim_geo,
                origin, wi, t_max, stack):
        return 0.0
    return 1.0


@kernel
def surface_shadow_call(S, p, n, wi, t_max, scale, medium, null_media, stack):
    """``surface_shadow`` as a call, for a site off the hot path (diffuse_entry's separate direct
    light): each inlined copy of the shadow-ray search adds to the cold compile time, and inlined
    (by LLVM) it rendered no faster (docs/performance.md, "Inlined by LLVM")."""
    return surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack)


@kernel
def backlight_transmission(S, mp, p, n, wo, wi, t_max, stack):
    """The backlight method's transmitted fraction for light arriving from behind along −wi.

    After Barré-Brisebois & Bouchard (GDC 2011), as in the seed lecture: the thickness is measured
    by a ray from p into the object towards the light; the transmitted share
    scale·e^{−σ_eff·thickness} (σ_eff per channel, from the diffusion approximation: see
    compile.py) goes into a lobe about a = normalize(−wo − distortion·n) (the view direction
    seen through the object, bent by the normal), (power + 1)/(2π)·max(0, wi·a)^power. The lobe
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
    ax = -wo[0] - mp[7] * ns[0]
    ay = -wo[1] - mp[7] * ns[1]
    az = -wo[2] - mp[7] * ns[2]
    inv = 1.0 / math.sqrt(ax * ax + ay * ay + az * az)
    c = (wi[0] * ax + wi[1] * ay + wi[2] * az) * inv
    if c <= 0.0:
        return 0.0, 0.0, 0.0
    lobe = (mp[8] + 1.0) / (2.0 * math.pi) * c ** mp[8]
    # Thickness: from just inside p towards the light, to where the ray leaves the object
    inside = spawn_offset(p, ns, wi, max(abs(p[0]), abs(p[1]), abs(p[2])))
    t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                      S.prim_kind, S.prim_geo, inside, wi, t_max, stack)
    if prim < 0:
        return 0.0, 0.0, 0.0
    q, nq = surface_point(S.prim_kind[prim], S.prim_geo[prim], inside, wi, t, u, v)
    if surface_shadow(S, q, nq, wi, t_max - t, S.prim_scale[prim], -1, False, stack) == 0.0:
        return 0.0, 0.0, 0.0
    k = mp[9] * lobe
    return k * math.exp(-mp[16] * t), k * math.exp(-mp[17] * t), k * math.exp(-mp[18] * t)


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
    d_ch = mp[16 + ch]
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
            pdf += prob / 3.0 * burley_pdf_area(r_proj, mp[16 + c]) * cos_n
    if not pdf > 0.0:
        return False, p, n, -1, none
    r_true = math.sqrt(r2)
    w = (mp[12] * burley_profile(r_true, mp[16]) / pdf,
         mp[13] * burley_profile(r_true, mp[17]) / pdf,
         mp[14] * burley_profile(r_true, mp[18]) / pdf)
    return True, chosen_p, chosen_n, chosen_prim, w


@kernel
def draw(S, key, dim, k, sidx, sob):
    """Value ``k`` of the block of dimensions that starts at ``dim``: independent (``uniform``),
    except at the first ``SOBOL_VERTICES`` vertices under the sobol sampler, where the light
    sample (k 0: the light, k 1-2: the point on it), the BSDF sample (k 3: the lobe, k 4-5: the
    direction) and the free flight (k 7) of each vertex come from their own shuffled, scrambled
    (0,2)-sequences (roulette, k 6, stays independent). ``sob`` holds the pixel's seeds of those
    sequences (``sobol_block_seeds``: row 0 the camera's, then five a vertex)."""
    if S.sampler[0] == 1 and dim < 2 + SOBOL_VERTICES * DIMS_PER_BOUNCE and k != 6:
        base = 1 + 5 * ((dim - 2) // DIMS_PER_BOUNCE)  # block 0 is the camera's
        if k == 0:
            b, c = base, 0
        elif k <= 2:
            b, c = base + 1, k - 1
        elif k == 3:
            b, c = base + 2, 0
        elif k <= 5:
            b, c = base + 3, k - 4
        else:
            b, c = base + 4, 0
        return sobol_value(sidx, sob[b, 0], sob[b, 1 + c], c)
    return uniform(key, dim + k)


@inline_kernel
def trace_path(S, o, d, key, stack, max_depth, sidx, sob):
    """Radiance arriving at o from direction −d along one sampled path. S is ``SceneArrays``;
    ``sidx`` (the sample's index) and ``sob`` (its pixel's sequence seeds) feed the sobol
    sampler's first ``SOBOL_VERTICES`` vertices (``draw``)."""
    lr = lg = lb = 0.0  # radiance gathered so far
    br = bg = bb = 1.0  # throughput β
    depth = 0  # scattering events so far
    # True when the previous vertex took no light sample (the camera, a delta BSDF, a medium
    # behind a refracting boundary): an emitter found next then counts in full, without MIS.
    unweighted = True
    prev_pdf = 0.0
    prev_p = o
    medium = -1  # material whose medium the ray travels in (−1: vacuum)
    # Product of η² over refractions: the η² radiance scaling is undone for roulette, which would
    # otherwise kill 60 % of the paths inside glass at every event (pbrt-v4's etaScale,
    # Mitsuba's `eta`).
    eta_scale = 1.0
    single_done = False  # the single-scatter medium the ray is in has had its one event
    skip_emission = False  # diffuse_entry with direct_light: this segment's light is counted apart
    dim = np.int64(2)  # not a literal: typed so, every draw() would compile twice (2, then int64)
    n_lights = S.light_kind.shape[0]
    env = S.env_light[0]
    null_media = S.null_media[0]
    for _ in range(MAX_SEGMENTS):
        # Find the closest surface along the ray
        t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                          S.prim_kind, S.prim_geo, o, d, math.inf,
                                          stack)

        # Inside a translucent medium: a free flight from exp(−σt·s) may end before the surface
        if medium >= 0 and single_done:
            # After its one scattering event, single-scattered light only attenuates on its way out
            br *= math.exp(-S.mat_param[medium, 4] * t)
            bg *= math.exp(-S.mat_param[medium, 4] * t)
            bb *= math.exp(-S.mat_param[medium, 4] * t)
        elif medium >= 0:
            mm = S.mat_param[medium]
            single = S.mat_kind[medium] == SINGLE_SCATTER
            s_flight = -math.log(1.0 - draw(S, key, dim, 7, sidx, sob)) / mm[4]
            if s_flight < t:
                if max_depth >= 0 and depth >= max_depth:
                    break
                p = (o[0] + s_flight * d[0], o[1] + s_flight * d[1], o[2] + s_flight * d[2])
                # σs/σt = albedo: the grey free flight leaves only the albedo as weight
                br *= mm[1]
                bg *= mm[2]
                bb *= mm[3]
                g = mm[5]
                single_done = single
                if (mm[0] == 1.0 or single) and n_lights > 0:
                    # Index-matched boundary: light sampling from inside the medium
                    wi, li_rgb, pdf_l, t_max, delta_l = sample_light(
                        S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf,
                        S.prim_kind, S.prim_geo, p, draw(S, key, dim, 0, sidx, sob),
                        draw(S, key, dim, 1, sidx, sob), draw(S, key, dim, 2, sidx, sob))
                    if pdf_l > 0.0:
                        if t_max < math.inf:
                            t_max *= 1.0 - SHADOW_SLACK
                        tr = transmittance(S, p, wi, t_max, medium, stack)
                        if tr > 0.0:
                            ph = hg_pdf(d[0] * wi[0] + d[1] * wi[1] + d[2] * wi[2], g)
                            w = tr * ph / pdf_l
                            if not delta_l:
                                w *= power_heuristic(pdf_l, ph)
                            lr += br * li_rgb[0] * w
                            lg += bg * li_rgb[1] * w
                            lb += bb * li_rgb[2] * w
                    unweighted = False
                else:
                    unweighted = True
                wi, prev_pdf = hg_sample(d, g, draw(S, key, dim, 3, sidx, sob),
                                         draw(S, key, dim, 4, sidx, sob))
                prev_p = p
                o = p
                d = wi
                depth += 1
                if depth >= RR_DEPTH:
                    # No cap below 1 in a medium: at albedo 0.999 a walk needs hundreds of events,
                    # and a 0.95 cap would make their weight heavy-tailed (1/0.95^k) for nothing;
                    # the albedo itself brings β and so the survival probability down.
                    alive, br, bg, bb = roulette(br, bg, bb, eta_scale, 1.0,
                                                 draw(S, key, dim, 6, sidx, sob))
                    if not alive:
                        break
                dim += DIMS_PER_BOUNCE
                continue
            # Otherwise the flight reaches the surface: P(s ≥ t) = exp(−σt t) = Tr(t), weight 1

        if prim < 0:
            # Escaped: the constant background, MIS-weighted against its light sample
            if env >= 0 and not skip_emission:
                w = 1.0
                if not unweighted:
                    w = power_heuristic(prev_pdf, S.light_pmf[env] * INV_4PI)
                lr += br * S.background[0] * w
                lg += bg * S.background[1] * w
                lb += bb * S.background[2] * w
            break

        kind = S.prim_kind[prim]
        geo = S.prim_geo[prim]
        p, n = surface_point(kind, geo, o, d, t, u, v)
        wo = (-d[0], -d[1], -d[2])
        cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
        mat = S.prim_material[prim]
        mk = S.mat_kind[mat]
        mp = S.mat_param[mat]
        scale = S.prim_scale[prim]

        # Beer–Lambert: a ray reaching a dielectric from inside crossed t of its medium
        if mk == DIELECTRIC and cos_o < 0.0:
            br *= math.exp(-mp[1] * t)
            bg *= math.exp(-mp[2] * t)
            bb *= math.exp(-mp[3] * t)

        # Emission from an area light's front side
        li = S.prim_light[prim]
        if li >= 0 and cos_o > 0.0 and not skip_emission:
            w = 1.0
            if not unweighted:
                w = power_heuristic(prev_pdf,
                                    area_light_pdf(S.light_pmf, li, kind, geo, prev_p, p, n))
            lr += br * S.light_data[li, 3] * w
            lg += bg * S.light_data[li, 4] * w
            lb += bb * S.light_data[li, 5] * w

        if mk == TRANSLUCENT and mp[0] == 1.0:
            # Index-matched boundary: the ray goes on unchanged into or out of the medium; this
            # is no scattering event (Mitsuba's null BSDF does not count towards depth either)
            medium = mat if d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < 0.0 else -1
            o = spawn_offset(p, n, d, scale)
            dim += DIMS_PER_BOUNCE
            continue
        skip_emission = False

        if mk == SINGLE_SCATTER and (cos_o < 0.0 or draw(S, key, dim, 3, sidx, sob) >= mp[7]):
            # The seed paper's model: 1 − surface_fraction of the hits go in, straight on (the
            # paper does not refract), to scatter at most once inside; leaving is straight too.
            # Shadow rays see the same surface (transmittance()), so MIS stays consistent.
            medium = mat if cos_o > 0.0 else -1
            single_done = False
            o = spawn_offset(p, n, d, scale)
            dim += DIMS_PER_BOUNCE
            continue

        if max_depth >= 0 and depth >= max_depth:
            break

        if mk == DIFFUSION:
            if cos_o <= 0.0:
                # Reached from inside (the camera in the object): leave straight, no event
                o = spawn_offset(p, n, d, scale)
                dim += DIMS_PER_BOUNCE
                continue
            # The smooth coat reflects F of the light: with probability F (the same uc and
            # Fresnel the boundary's bsdf_sample below uses) the generic code takes the mirror
            # direction; the rest (1 − F, cancelled by its probability) goes under the surface.
            f_o, _ = fresnel_dielectric(cos_o, mp[0])
            if draw(S, key, dim, 3, sidx, sob) >= f_o:
                if mp[10] > 0.0:
                    # Effectively opaque (auto, renderer/materials/opaque.py): the profile is
                    # narrower than a pixel, so the light leaves where it entered, with
                    # probability A: the separable BSSRDF's zero-radius limit, a BRDF
                    ok, p_o, n_o, prim_o, w = True, p, n, prim, (mp[12], mp[13], mp[14])
                else:
                    ok, p_o, n_o, prim_o, w = diffusion_probe(S, mat, p, n, mp,
                                                              key ^ np.uint64(dim), stack)
                if not ok:
                    break
                br *= w[0]
                bg *= w[1]
                bb *= w[2]
                depth += 1
                if max_depth >= 0 and depth >= max_depth:
                    break
                # Carry on from the exit vertex, lit through S_w (a diffuse-like lobe)
                p = p_o
                n = n_o
                wo = n_o
                mk = DIFFUSION_EXIT
                scale = S.prim_scale[prim_o]

        # Next-event estimation: one light sample, MIS-weighted against the BSDF
        delta = is_delta(mk)
        if n_lights > 0 and not delta:
            wi, li_rgb, pdf_l, t_max, delta_l = sample_light(
                S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf, S.prim_kind,
                S.prim_geo, p, draw(S, key, dim, 0, sidx, sob), draw(S, key, dim, 1, sidx, sob),
                draw(S, key, dim, 2, sidx, sob))
            if pdf_l > 0.0:
                f = bsdf_eval(mk, mp, wo, wi, n)
                if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
                    tr = surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack)
                    if tr > 0.0:
                        w = tr / pdf_l
                        if not delta_l:
                            w *= power_heuristic(pdf_l, bsdf_pdf(mk, mp, wo, wi, n))
                        lr += br * f[0] * li_rgb[0] * w
                        lg += bg * f[1] * li_rgb[1] * w
                        lb += bb * f[2] * li_rgb[2] * w
                elif mk == BACKLIGHT:
                    # The light is behind the surface: the backlight approximation's term
                    tr, tg, tb = backlight_transmission(S, mp, p, n, wo, wi, t_max, stack)
                    lr += br * mp[1] * li_rgb[0] * tr / pdf_l
                    lg += bg * mp[2] * li_rgb[1] * tg / pdf_l
                    lb += bb * mp[3] * li_rgb[2] * tb / pdf_l

        if mk == DIFFUSE_ENTRY and mp[7] > 0.0 and cos_o > 0.0 and n_lights > 0:
            # The student project's separate direct light: what enters here and comes back out
            # is lit as a Lambertian surface of albedo (1 − F)·colour; the light that the walk
            # below would carry straight out to a light is not counted again (skip_emission)
            wi, li_rgb, pdf_l, t_max, delta_l = sample_light(
                S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf, S.prim_kind,
                S.prim_geo, p, draw(S, key, dim, 0, sidx, sob), draw(S, key, dim, 1, sidx, sob),
                draw(S, key, dim, 2, sidx, sob))
            cos_l = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
            if pdf_l > 0.0 and cos_l > 0.0:
                tr = surface_shadow_call(S, p, n, wi, t_max, scale, -1, null_media, stack)
                if tr > 0.0:
                    f_in, _ = fresnel_dielectric(cos_o, mp[0])
                    w = tr * (1.0 - f_in) * cos_l / (math.pi * pdf_l)
                    lr += br * mp[1] * li_rgb[0] * w
                    lg += bg * mp[2] * li_rgb[1] * w
                    lb += bb * mp[3] * li_rgb[2] * w

        # Sample the BSDF for the next direction
        wi, weight, pdf, ok = bsdf_sample(mk, mp, wo, n, draw(S, key, dim, 3, sidx, sob),
                                          draw(S, key, dim, 4, sidx, sob),
                                          draw(S, key, dim, 5, sidx, sob))
        if not ok:
            break
        if mk == DIFFUSE_ENTRY:
            into = wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0
            if cos_o > 0.0 and into:
                # The student project's rule: a ray that enters scatters at once, just inside,
                # about its refracted direction (g is the bias), multiplied by the colour
                ws, _ = hg_sample(wi, mp[5], draw(S, key, dim, 4, sidx, sob),
                                  draw(S, key, dim, 5, sidx, sob))
                c = ws[0] * n[0] + ws[1] * n[1] + ws[2] * n[2]
                if c > 0.0:  # keep it inside: mirror it about the surface
                    ws = (ws[0] - 2.0 * c * n[0], ws[1] - 2.0 * c * n[1], ws[2] - 2.0 * c * n[2])
                wi = ws
                weight = (weight[0] * mp[1], weight[1] * mp[2], weight[2] * mp[3])
            elif cos_o > 0.0 and mp[8] > 0.0:
                # Glossy coat: a normalized Phong lobe about the mirror direction, f·cos/pdf =
                # (n + 2)/(n + 1)·cos θi
                wg = to_world(phong_lobe(draw(S, key, dim, 4, sidx, sob),
                                         draw(S, key, dim, 5, sidx, sob), mp[8]), wi)
                c = wg[0] * n[0] + wg[1] * n[1] + wg[2] * n[2]
                if c <= 0.0:
                    break
                wi = wg
                k = (mp[8] + 2.0) / (mp[8] + 1.0) * c
                weight = (k, k, k)
            elif cos_o < 0.0 and not into and mp[7] > 0.0:
                skip_emission = True
        br *= weight[0]
        bg *= weight[1]
        bb *= weight[2]
        if br == 0.0 and bg == 0.0 and bb == 0.0:
            break
        if mk == TRANSLUCENT or mk == DIFFUSE_ENTRY:
            # Refracted in or out, or reflected: the side wi leaves on decides the medium
            medium = mat if wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0 else -1
        if (mk == DIELECTRIC or mk == TRANSLUCENT) and weight[0] != 1.0:
            eta_scale /= weight[0]  # a refraction: the weight was (η_i/η_t)²
        elif mk == DIFFUSE_ENTRY and (cos_o > 0.0) != (wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2]
                                                         > 0.0):
            eta_scale *= mp[0] * mp[0] if cos_o > 0.0 else 1.0 / (mp[0] * mp[0])
        unweighted = delta
        prev_pdf = pdf
        prev_p = p
        depth += 1
        o = spawn_offset(p, n, wi, scale)
        d = wi

        # Russian roulette
        if depth >= RR_DEPTH:
            alive, br, bg, bb = roulette(br, bg, bb, eta_scale, RR_MAX,
                                         draw(S, key, dim, 6, sidx, sob))
            if not alive:
                break
        dim += DIMS_PER_BOUNCE
    return lr, lg, lb


@kernel
def camera_ray(cam, width, height, x, y, jx, jy):
    """Pinhole camera: a ray through the point (x + jx, y + jy) of the film; row 0 is the top."""
    sx = (2.0 * (x + jx) / width - 1.0) * cam[12] * cam[13]
    sy = (1.0 - 2.0 * (y + jy) / height) * cam[12]
    dx = cam[3] + sx * cam[6] + sy * cam[9]
    dy = cam[4] + sx * cam[7] + sy * cam[10]
    dz = cam[5] + sx * cam[8] + sy * cam[11]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return (cam[0], cam[1], cam[2]), (dx * inv, dy * inv, dz * inv)


@kernel
def render_row(S, width, height, seed, max_depth, x0, y, row, tile_w, sample_start,
               sample_count, active, out_sum, out_sum_sq, out_count, out_dropped, stack, sob):
    """Add the samples of one row of a tile (``render_tile_kernel``'s unit of work). ``sob`` is
    (SOBOL_BLOCKS, 3) scratch for the sobol sampler's seeds of a pixel."""
    for col in range(tile_w):
        if active[row, col] == 0:
            continue
        x = x0 + col
        pixel = y * width + x
        if S.sampler[0] == 1:
            # The sobol sampler's scrambles of this pixel (a hash apart from every sample's key)
            sobol_block_seeds(mix64(sample_key(seed, pixel, 0) ^ PIXEL_SEED_SALT), sob)
        sr = sg = sb = 0.0
        qr = qg = qb = 0.0
        good = 0
        bad = 0
        for s in range(sample_start, sample_start + sample_count):
            key = sample_key(seed, pixel, s)
            if S.sampler[0] == 1:
                jx = sobol_value(s, sob[0, 0], sob[0, 1], 0)
                jy = sobol_value(s, sob[0, 0], sob[0, 2], 1)
            else:
                jx = uniform(key, 0)
                jy = uniform(key, 1)
            o, d = camera_ray(S.camera, width, height, x, y, jx, jy)
            r, g, b = trace_path(S, o, d, key, stack, max_depth, s, sob)
            # Dropped also when the square overflows, so the variance sums stay finite
            if math.isfinite(r * r) and math.isfinite(g * g) and math.isfinite(b * b):
                sr += r
                sg += g
                sb += b
                qr += r * r
                qg += g * g
                qb += b * b
                good += 1
            else:
                bad += 1
        out_sum[row, col, 0] += sr
        out_sum[row, col, 1] += sg
        out_sum[row, col, 2] += sb
        out_sum_sq[row, col, 0] += qr
        out_sum_sq[row, col, 1] += qg
        out_sum_sq[row, col, 2] += qb
        out_count[row, col] += good
        out_dropped[row, col] += bad


@parallel_kernel
def render_tile_kernel(S, width, height, seed, max_depth, stack_size, x0, y0, tile_w, tile_h,
                       sample_start, sample_count, active, out_sum, out_sum_sq, out_count,
                       out_dropped, n_threads):
    """Add samples [sample_start, sample_start + sample_count) of every pixel of a tile.

    Rows are shared among ``n_threads`` of numba's threads; a sample whose radiance is not finite
    (or whose square overflows, |L| > 1e154) is not added but counted in ``out_dropped``, so a bad
    path can never turn a pixel into NaN or inf unnoticed. Pixels whose ``active`` flag is 0
    (adaptive sampling: converged) get no samples.
    """
    # Rows are dealt out in turn (thread c takes rows c, c + n, c + 2n, …) rather than in n
    # contiguous blocks, so a thread whose block holds the costly part of the frame (a translucent
    # object filling the lower half) does not leave the others idle at the end.
    # (numba.get_num_threads() inside the kernel would make it uncacheable: the host passes it.)
    n_chunks = max(1, min(tile_h, n_threads))
    for chunk in prange(n_chunks):
        stack = traversal_stack(stack_size)
        sob = np.zeros((SOBOL_BLOCKS, 3), np.uint64)
        for row in range(chunk, tile_h, n_chunks):
            render_row(S, width, height, seed, max_depth, x0, y0 + row, row, tile_w,
                       sample_start, sample_count, active, out_sum, out_sum_sq, out_count,
                       out_dropped, stack, sob)
