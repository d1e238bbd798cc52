"""What a shadow ray lets through: occlusion, and transmittance across null boundaries.

A shadow ray is blocked by any surface, except those a light path crosses without changing
direction: the boundary of an index-matched translucent medium (``IOR`` 1: it neither reflects
nor refracts) and the seed paper's single-scatter surface (1 − surface_fraction of the light goes
in, straight on). Across those, the ray carries the media's transmittance exp(−σt·length).
``surface_shadow`` is the shadow ray of a surface vertex, ``transmittance`` that of a vertex
inside a medium; ``renderer.integrators.direct`` and the subsurface methods call them.
"""

from __future__ import annotations

import math

from renderer.geometry.bvh import intersect_closest, occluded
from renderer.geometry.flat import flat_planar_t
from renderer.geometry.shapes import (
    SPAWN_EPSILON,
    SPHERE,
    spawn_offset,
    sphere_roots,
    surface_point,
)
from renderer.jit import inline_kernel, kernel
from renderer.materials.bsdf import SINGLE_SCATTER, TRANSLUCENT
from renderer.materials.translucent import IOR, SIGMA_T, SURFACE_FRACTION

# A shadow ray stops this fraction of its length (plus SPAWN_EPSILON of the light point's
# coordinates) short of the light point it aims at, so it does not hit the light's own surface;
# sampled points are exact to ~1e-15 relative.
SHADOW_SLACK = 1e-7


@inline_kernel
def shadow_passable(S, mat):
    """A shadow ray may cross a surface of material ``mat``: an index-matched translucent medium's
    boundary or a single-scatter object's (see transmittance)."""
    kind = S.mat_kind[mat]
    return (kind == TRANSLUCENT and S.mat_param[mat, IOR] == 1.0) or kind == SINGLE_SCATTER


@inline_kernel
def transmittance(S, o, d, t_max, medium, stack):
    """Fraction of light (RGB) that travels from o to o + t_max·d: 0 when a surface blocks it,
    else exp(−σt·length), σt per channel, over the stretches inside index-matched translucent
    media (their boundaries neither reflect nor refract, so a shadow ray may cross them) and
    single-scatter objects (whose surface lets 1 − surface_fraction of the light in, straight
    on). ``medium`` is the material of the medium at o (−1: vacuum).

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
    the integrator cost compile time; inlined by LLVM, the renders were no faster
    (docs/performance.md, "Start-up", "Inlined by LLVM")."""
    tr_r = tr_g = tr_b = 1.0
    for _ in range(64):
        t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                          S.prim_kind, S.prim_geo, o, d, t_max, stack)
        if medium >= 0:
            s = min(t, t_max)
            tr_r *= math.exp(-S.mat_param[medium, SIGMA_T] * s)
            tr_g *= math.exp(-S.mat_param[medium, SIGMA_T + 1] * s)
            tr_b *= math.exp(-S.mat_param[medium, SIGMA_T + 2] * s)
        if prim < 0:
            return tr_r, tr_g, tr_b
        mat = S.prim_material[prim]
        kind = S.mat_kind[mat]
        if not shadow_passable(S, mat) or (tr_r == 0.0 and tr_g == 0.0 and tr_b == 0.0):
            return 0.0, 0.0, 0.0
        p, n = surface_point(S.prim_kind[prim], S.prim_geo[prim], o, d, t, u, v)
        entering = d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < 0.0
        if entering and kind == SINGLE_SCATTER:
            f = 1.0 - S.mat_param[mat, SURFACE_FRACTION]
            tr_r, tr_g, tr_b = tr_r * f, tr_g * f, tr_b * f
        medium = mat if entering else -1
        o2 = spawn_offset(p, n, d, S.prim_scale[prim])
        t_max -= (o2[0] - o[0]) * d[0] + (o2[1] - o[1]) * d[1] + (o2[2] - o[2]) * d[2]
        o = o2
    return 0.0, 0.0, 0.0


@inline_kernel
def crossing(S, mat, t, entering, tau, open_sigma, n_open, tr):
    """One crossing of ``flat_transmittance``'s sum: (tau, open_sigma, n_open, tr) after it;
    tau and open_sigma per channel."""
    sr = S.mat_param[mat, SIGMA_T]
    sg = S.mat_param[mat, SIGMA_T + 1]
    sb = S.mat_param[mat, SIGMA_T + 2]
    if entering:
        if S.mat_kind[mat] == SINGLE_SCATTER:
            tr *= 1.0 - S.mat_param[mat, SURFACE_FRACTION]
        return ((tau[0] - sr * t, tau[1] - sg * t, tau[2] - sb * t),
                (open_sigma[0] + sr, open_sigma[1] + sg, open_sigma[2] + sb), n_open + 1, tr)
    return ((tau[0] + sr * t, tau[1] + sg * t, tau[2] + sb * t),
            (open_sigma[0] - sr, open_sigma[1] - sg, open_sigma[2] - sb), n_open - 1, tr)


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
    tau = (0.0, 0.0, 0.0)
    open_sigma = (0.0, 0.0, 0.0)
    if medium >= 0:
        open_sigma = (S.mat_param[medium, SIGMA_T], S.mat_param[medium, SIGMA_T + 1],
                      S.mat_param[medium, SIGMA_T + 2])
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
                return 0.0, 0.0, 0.0
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
                return 0.0, 0.0, 0.0
            g = S.prim_geo[k]
            # d·(e1 × e2): the sign that tells entering (< 0) from leaving, as surface_point's
            # outward normal does
            dn = (d[0] * (g[4] * g[8] - g[5] * g[7]) + d[1] * (g[5] * g[6] - g[3] * g[8])
                  + d[2] * (g[3] * g[7] - g[4] * g[6]))
            tau, open_sigma, n_open, tr = crossing(S, mat, t, dn < 0.0, tau, open_sigma,
                                                   n_open, tr)
    if n_open > 0:
        tau = (tau[0] + open_sigma[0] * t_max, tau[1] + open_sigma[1] * t_max,
               tau[2] + open_sigma[2] * t_max)
    return (tr * math.exp(-max(tau[0], 0.0)), tr * math.exp(-max(tau[1], 0.0)),
            tr * math.exp(-max(tau[2], 0.0)))


@inline_kernel
def surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack):
    """Transmittance (RGB) of the shadow ray from surface point p towards a light t_max away
    along wi.

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
        return 0.0, 0.0, 0.0
    return 1.0, 1.0, 1.0


@kernel
def surface_shadow_call(S, p, n, wi, t_max, scale, medium, null_media, stack):
    """``surface_shadow`` as a call, for a site off the hot path (diffuse_entry's separate direct
    light): each inlined copy of the shadow-ray search adds to the cold compile time, and inlined
    (by LLVM) it rendered no faster (docs/performance.md, "Inlined by LLVM")."""
    return surface_shadow(S, p, n, wi, t_max, scale, medium, null_media, stack)
