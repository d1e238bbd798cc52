"""The stages of the wavefront path tracer: each one's work on one path, and its CPU loop.

A ``*_one`` function does a stage's work for the path in slot i of the state ``P``
(``renderer.wavefront.state``) of scene ``S`` (``SceneArrays``): pure functions of arrays and
numbers, which the CPU stages below run over a queue of slots in numba's threads, and
``renderer.wavefront.gpu`` runs one CUDA thread a slot (numba's CUDA target compiles a CPU
function called from a kernel as a device function). The arithmetic is the scalar kernel's
(``renderer.integrators.path.trace_path``) for the surface materials, step for step, with the same
random dimension for each decision (``renderer.integrators.sampler``: 0–2 the light sample, 3–5
the BSDF's, 6 roulette), so a path here is the scalar kernel's path and the images agree to
rounding.
"""

from __future__ import annotations

import math

from numba import prange

from renderer.film.samples import add_sample
from renderer.geometry.bvh import intersect_closest, traversal_stack
from renderer.geometry.shapes import spawn_offset, surface_point
from renderer.integrators.path import camera_ray, escaped_radiance
from renderer.integrators.roulette import RR_DEPTH, RR_MAX, survive
from renderer.integrators.sampler import DIMS_PER_BOUNCE
from renderer.integrators.shadow import surface_shadow
from renderer.jit import inline_kernel, kernel, parallel_kernel
from renderer.lights import area_light_pdf, sample_light
from renderer.materials.bsdf import (
    DIELECTRIC,
    ROUGH_DIELECTRIC,
    bsdf_eval,
    bsdf_pdf,
    bsdf_sample,
    is_delta,
)
from renderer.materials.dielectric import IOR, absorbed
from renderer.rng import sample_key, uniform
from renderer.sampling import power_heuristic


@inline_kernel
def work_item(first, g):
    """The work item (pixel) whose samples hold path g of the work: the w with
    ``first[w] ≤ g < first[w + 1]``, by bisection (``first`` increases strictly)."""
    lo = 0
    hi = first.shape[0] - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if first[mid] <= g:
            lo = mid
        else:
            hi = mid
    return lo


@inline_kernel
def work_sample(g, x0, y0, tile_w, work, first, sample_start):
    """Path g of a tile's work: (work item w, sample index s, pixel x, y). Work item w is the
    pixel ``work[w]`` (its index in the tile, row-major); its paths are ``first[w]`` …
    ``first[w + 1] − 1``, samples ``sample_start`` onwards (``renderer.wavefront.cpu.batching``)."""
    w = work_item(first, g)
    slot = work[w]
    row = slot // tile_w
    return w, sample_start + g - first[w], x0 + slot - row * tile_w, y0 + row


@inline_kernel
def generate_one(S, P, i, width, height, seed, x0, y0, tile_w, work, first, sample_start, g):
    """Start path i as path g of the tile's work (``work_sample``): its camera ray, jittered by
    dimensions 0 and 1."""
    w, s, x, y = work_sample(g, x0, y0, tile_w, work, first, sample_start)
    key = sample_key(seed, y * width + x, s)
    o, d = camera_ray(S.camera, width, height, x, y, uniform(key, 0), uniform(key, 1))
    P.work[i] = w
    P.sample[i] = s
    P.key[i] = key
    for a in range(3):
        P.o[i, a] = o[a]
        P.d[i, a] = d[a]
        P.beta[i, a] = 1.0
        P.L[i, a] = 0.0
        P.prev_p[i, a] = o[a]
    P.eta_scale[i] = 1.0
    P.depth[i] = 0
    P.dim[i] = 2
    P.unweighted[i] = 1
    P.prev_pdf[i] = 0.0
    P.alive[i] = 1
    P.shadow_t[i] = -1.0


@inline_kernel
def intersect_one(S, P, i, stack):
    """The closest surface along path i's ray (``hit_prim`` −1: none)."""
    t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                      S.prim_kind, S.prim_geo, (P.o[i, 0], P.o[i, 1], P.o[i, 2]),
                                      (P.d[i, 0], P.d[i, 1], P.d[i, 2]), math.inf, stack)
    P.hit_t[i] = t
    P.hit_prim[i] = prim
    P.hit_u[i] = u
    P.hit_v[i] = v


@inline_kernel
def escaped_one(S, P, i, d):
    """A ray that left the scene: the constant background or the environment image, MIS-weighted
    against its light sample; the path ends."""
    env = S.env_light[0]
    if env >= 0:
        le, pdf_env = escaped_radiance(S, env, d)
        w = 1.0
        if P.unweighted[i] == 0:
            w = power_heuristic(P.prev_pdf[i], S.light_pmf[env] * pdf_env)
        for a in range(3):
            P.L[i, a] = P.L[i, a] + P.beta[i, a] * le[a] * w
    P.alive[i] = 0


@inline_kernel
def light_sample_one(S, P, i, mk, mp, p, n, wo, scale):
    """Next-event estimation at a non-delta vertex: one light sample and its MIS weight against
    the BSDF (``renderer.integrators.direct.surface_direct``'s arithmetic with an unoccluded
    shadow ray), left in the shadow fields for the shadow stage to test."""
    key = P.key[i]
    dim = P.dim[i]
    wi, li_rgb, pdf_l, t_max, delta_l = sample_light(
        S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf, S.prim_kind,
        S.prim_geo, S.env_image, S.env_marginal, S.env_conditional, S.env_rotation, p,
        uniform(key, dim), uniform(key, dim + 1), uniform(key, dim + 2))
    if not pdf_l > 0.0:
        return
    f = bsdf_eval(mk, mp, wo, wi, n)
    if not (f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0):
        return
    wr = wg = wb = 1.0 / pdf_l
    if not delta_l:
        mis = power_heuristic(pdf_l, bsdf_pdf(mk, mp, wo, wi, n))
        wr, wg, wb = wr * mis, wg * mis, wb * mis
    P.shadow_c[i, 0] = P.beta[i, 0] * f[0] * li_rgb[0] * wr
    P.shadow_c[i, 1] = P.beta[i, 1] * f[1] * li_rgb[1] * wg
    P.shadow_c[i, 2] = P.beta[i, 2] * f[2] * li_rgb[2] * wb
    for a in range(3):
        P.shadow_p[i, a] = p[a]
        P.shadow_n[i, a] = n[a]
        P.shadow_wi[i, a] = wi[a]
    P.shadow_t[i] = t_max
    P.shadow_scale[i] = scale


@inline_kernel
def shade_one(S, P, i, max_depth):
    """Path i at its hit: escaped or emitter light, the depth limit, a light sample
    (``light_sample_one``), the BSDF's sample for the next ray, and Russian roulette."""
    P.shadow_t[i] = -1.0
    d = (P.d[i, 0], P.d[i, 1], P.d[i, 2])
    prim = P.hit_prim[i]
    if prim < 0:
        escaped_one(S, P, i, d)
        return
    key = P.key[i]
    dim = P.dim[i]
    depth = P.depth[i]

    # The surface point and its material
    t = P.hit_t[i]
    kind, geo, mat = S.prim_kind[prim], S.prim_geo[prim], S.prim_material[prim]
    mk, mp, scale = S.mat_kind[mat], S.mat_param[mat], S.prim_scale[prim]
    p, n = surface_point(kind, geo, (P.o[i, 0], P.o[i, 1], P.o[i, 2]), d, t, P.hit_u[i],
                         P.hit_v[i])
    wo = (-d[0], -d[1], -d[2])
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    br, bg, bb = P.beta[i, 0], P.beta[i, 1], P.beta[i, 2]

    # Beer–Lambert: a ray reaching a dielectric from inside crossed t of its medium
    if (mk == DIELECTRIC or mk == ROUGH_DIELECTRIC) and cos_o < 0.0:
        br, bg, bb = absorbed(mp, t, br, bg, bb)
        P.beta[i, 0], P.beta[i, 1], P.beta[i, 2] = br, bg, bb

    # Emission from an area light's front side, MIS-weighted against its light sample
    li = S.prim_light[prim]
    if li >= 0 and cos_o > 0.0:
        w = 1.0
        if P.unweighted[i] == 0:
            prev_p = (P.prev_p[i, 0], P.prev_p[i, 1], P.prev_p[i, 2])
            w = power_heuristic(P.prev_pdf[i],
                                area_light_pdf(S.light_pmf, li, kind, geo, prev_p, p, n))
        P.L[i, 0] = P.L[i, 0] + br * S.light_data[li, 3] * w
        P.L[i, 1] = P.L[i, 1] + bg * S.light_data[li, 4] * w
        P.L[i, 2] = P.L[i, 2] + bb * S.light_data[li, 5] * w
    if max_depth >= 0 and depth >= max_depth:
        P.alive[i] = 0
        return

    # Next-event estimation: one light sample, traced by the shadow stage
    delta = is_delta(mk)
    if S.light_kind.shape[0] > 0 and not delta:
        light_sample_one(S, P, i, mk, mp, p, n, wo, scale)

    # The BSDF's sample for the next direction
    wi, weight, pdf, ok = bsdf_sample(mk, mp, wo, n, uniform(key, dim + 3),
                                      uniform(key, dim + 4), uniform(key, dim + 5))
    if not ok:
        P.alive[i] = 0
        return
    br, bg, bb = br * weight[0], bg * weight[1], bb * weight[2]
    if br == 0.0 and bg == 0.0 and bb == 0.0:
        P.alive[i] = 0
        return
    eta_scale = P.eta_scale[i]
    if mk == DIELECTRIC and weight[0] != 1.0:
        eta_scale /= weight[0]  # a refraction: the weight was (η_i/η_t)²
    elif mk == ROUGH_DIELECTRIC and (cos_o > 0.0) != (
            wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0.0):
        eta_scale *= mp[IOR] * mp[IOR] if cos_o > 0.0 else 1.0 / (mp[IOR] * mp[IOR])
    depth += 1
    o = spawn_offset(p, n, wi, scale)
    for a in range(3):
        P.prev_p[i, a] = p[a]
        P.o[i, a] = o[a]
        P.d[i, a] = wi[a]
    P.unweighted[i] = 1 if delta else 0
    P.prev_pdf[i] = pdf
    P.depth[i] = depth
    P.eta_scale[i] = eta_scale

    # Russian roulette (renderer.integrators.roulette), from the RR_DEPTH-th event
    if depth >= RR_DEPTH:
        alive, br, bg, bb = survive(br, bg, bb, eta_scale, RR_MAX, uniform(key, dim + 6))
        if not alive:
            P.alive[i] = 0
            return
    P.beta[i, 0], P.beta[i, 1], P.beta[i, 2] = br, bg, bb
    P.dim[i] = dim + DIMS_PER_BOUNCE


@inline_kernel
def shadow_one(S, P, i, stack):
    """The shadow ray of path i's light sample: its contribution is added when nothing blocks
    it (``renderer.integrators.shadow.surface_shadow``, plain occlusion)."""
    if P.shadow_t[i] < 0.0:
        return
    tr = surface_shadow(S, (P.shadow_p[i, 0], P.shadow_p[i, 1], P.shadow_p[i, 2]),
                        (P.shadow_n[i, 0], P.shadow_n[i, 1], P.shadow_n[i, 2]),
                        (P.shadow_wi[i, 0], P.shadow_wi[i, 1], P.shadow_wi[i, 2]),
                        P.shadow_t[i], P.shadow_scale[i], -1, False, stack)
    if tr[0] > 0.0:
        for a in range(3):
            P.L[i, a] = P.L[i, a] + P.shadow_c[i, a]


@inline_kernel
def accumulate_one(P, w, g0, first, work, out_sum, out_sum_sq, out_count, out_dropped, tile_w):
    """Add the samples of work item w (a pixel), paths ``first[w]`` … ``first[w + 1] − 1`` of the
    tile's work, in slots from ``g0`` (its batch's first path), to its pixel of the sample buffer
    in sample order; a sample that is not finite (or whose square overflows) is dropped and
    counted, as in the scalar kernel."""
    slot = work[w]
    row = slot // tile_w
    col = slot - row * tile_w
    for g in range(first[w], first[w + 1]):
        i = g - g0
        add_sample(out_sum, out_sum_sq, out_count, out_dropped, row, col, P.L[i, 0], P.L[i, 1],
                   P.L[i, 2])


# --- the CPU stages: each a parallel loop over a queue of path slots ------------------------------
# Each parallel stage cuts the queue into one contiguous run a thread and hands each run to a
# serial kernel (``*_run``) compiled without numba's runtime: inside a parallel loop every array
# taken out of the ``S`` and ``P`` tuples is reference-counted (an atomic increment and decrement
# an access, renderer/jit.py), which made each stage cost about what the scalar kernel's whole
# path does.


@kernel
def generate_run(S, P, width, height, seed, x0, y0, tile_w, work, first, sample_start, g0, lo,
                 hi, live):
    for i in range(lo, hi):
        generate_one(S, P, i, width, height, seed, x0, y0, tile_w, work, first, sample_start,
                     g0 + i)
        live[i] = i


@parallel_kernel
def generate(S, P, width, height, seed, x0, y0, tile_w, work, first, sample_start, g0, n, live,
             n_threads):
    """Start paths 0 … n − 1 as paths g0 … g0 + n − 1 of the work; all of them are live."""
    n_chunks = max(1, min(n, n_threads))
    for c in prange(n_chunks):
        generate_run(S, P, width, height, seed, x0, y0, tile_w, work, first, sample_start, g0,
                     c * n // n_chunks, (c + 1) * n // n_chunks, live)


@kernel
def trace_run(S, P, live, lo, hi, stack, shadow_rays):
    for j in range(lo, hi):
        if shadow_rays:
            shadow_one(S, P, live[j], stack)
        else:
            intersect_one(S, P, live[j], stack)


@parallel_kernel
def trace_rays(S, P, live, n_live, stack_size, n_threads, shadow_rays):
    """The live paths' ray queries, each run of the queue with its traversal stack: their
    closest hits (``intersect_one``), or with ``shadow_rays`` their light samples' shadow rays
    (``shadow_one``)."""
    n_chunks = max(1, min(n_live, n_threads))
    for c in prange(n_chunks):
        trace_run(S, P, live, c * n_live // n_chunks, (c + 1) * n_live // n_chunks,
                  traversal_stack(stack_size), shadow_rays)


def intersect(S, P, live, n_live, stack_size, n_threads):
    """Closest hits of the live paths."""
    trace_rays(S, P, live, n_live, stack_size, n_threads, False)


def shadow(S, P, live, n_live, stack_size, n_threads):
    """The shadow rays of the live paths' light samples."""
    trace_rays(S, P, live, n_live, stack_size, n_threads, True)


@kernel
def shade_run(S, P, live, lo, hi, max_depth):
    for j in range(lo, hi):
        shade_one(S, P, live[j], max_depth)


@parallel_kernel
def shade(S, P, live, n_live, max_depth, n_threads):
    n_chunks = max(1, min(n_live, n_threads))
    for c in prange(n_chunks):
        shade_run(S, P, live, c * n_live // n_chunks, (c + 1) * n_live // n_chunks, max_depth)


@kernel
def compact(P, live, n_live):
    """Keep the live paths at the front of the queue, in order; returns how many."""
    k = 0
    for j in range(n_live):
        i = live[j]
        if P.alive[i] != 0:
            live[k] = i
            k += 1
    return k


@parallel_kernel
def accumulate(P, w0, w1, first, work, out_sum, out_sum_sq, out_count, out_dropped, tile_w):
    """Add the batch of work items w0 … w1 − 1 (whole pixels: its paths are ``first[w0]`` …
    ``first[w1] − 1``, in slots from 0) to the sample buffer, a pixel a task."""
    for w in prange(w0, w1):
        accumulate_one(P, w, first[w0], first, work, out_sum, out_sum_sq, out_count,
                       out_dropped, tile_w)
