"""Unidirectional path tracing with next-event estimation and multiple importance sampling.

The structure is pbrt-v4's PathIntegrator::Li. At every non-delta vertex one light sample
(``renderer.lights``) and one BSDF sample are taken; where both strategies can reach the same
light (area lights and the background), each is weighted by Veach's power heuristic, and delta
lights (point, directional) take the light sample alone. Paths are ended by Russian roulette from
``RR_DEPTH`` scattering events on, with survival probability min(max(β), 0.95) as in Mitsuba 3, so
an unlimited ``max_depth`` (-1) stays unbiased.

``max_depth`` counts scattering events (scene format v1): 0 shows only what the camera sees
directly, 1 adds direct lighting. Mitsuba's ``max_depth`` counts path segments, one more.

Random numbers: dimensions 0 and 1 jitter the pixel; each scattering event then uses the
``DIMS_PER_BOUNCE`` dimensions that follow, always the same ones for the same role, so one
sample's path is a pure function of (seed, pixel, sample index) — see ``renderer.rng``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from renderer.geometry.bvh import intersect_closest, occluded
from renderer.geometry.shapes import SPAWN_EPSILON, spawn_offset, surface_point
from renderer.jit import kernel, parallel_kernel
from renderer.lights import area_light_pdf, sample_light
from renderer.materials.bsdf import DIELECTRIC, bsdf_eval, bsdf_pdf, bsdf_sample, is_delta
from renderer.rng import sample_key, uniform
from renderer.sampling import INV_4PI, power_heuristic

RR_DEPTH = 5
DIMS_PER_BOUNCE = 8
# A guard against a path that never ends (a ray trapped between two perfect mirrors with
# roulette surviving at 0.95 still ends, but only with probability one); 2¹⁶ events survive
# roulette with probability 0.95^65531 ≈ 10⁻¹⁴⁶⁰, so the cap never biases an image.
MAX_EVENTS = 1 << 16
# A shadow ray stops this fraction of its length (plus SPAWN_EPSILON of the light point's
# coordinates) short of the light point it aims at, so it does not hit the light's own surface;
# sampled points are exact to ~1e-15 relative.
SHADOW_SLACK = 1e-7


@kernel
def trace_path(S, o, d, key, stack, max_depth):
    """Radiance arriving at o from direction −d along one sampled path. S is ``SceneArrays``."""
    lr = lg = lb = 0.0  # radiance gathered so far
    br = bg = bb = 1.0  # throughput β
    depth = 0  # scattering events so far
    specular = True  # no MIS for emission hit after the camera or a delta event
    prev_pdf = 0.0
    prev_p = o
    dim = 2
    n_lights = S.light_kind.shape[0]
    env = S.env_light[0]
    while depth < MAX_EVENTS:
        # Find the closest surface along the ray
        t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_offset, S.bvh_count,
                                          S.bvh_axis, S.prim_kind, S.prim_geo, o, d, math.inf,
                                          stack)
        if prim < 0:
            # Escaped: the constant background, MIS-weighted against its light sample
            if env >= 0:
                w = 1.0
                if not specular:
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

        # Beer–Lambert: a ray reaching a dielectric from inside crossed t of its medium
        if mk == DIELECTRIC and cos_o < 0.0:
            br *= math.exp(-mp[1] * t)
            bg *= math.exp(-mp[2] * t)
            bb *= math.exp(-mp[3] * t)

        # Emission from an area light's front side
        li = S.prim_light[prim]
        if li >= 0 and cos_o > 0.0:
            w = 1.0
            if not specular:
                w = power_heuristic(prev_pdf,
                                    area_light_pdf(S.light_pmf, li, kind, geo, prev_p, p, n))
            lr += br * S.light_data[li, 3] * w
            lg += bg * S.light_data[li, 4] * w
            lb += bb * S.light_data[li, 5] * w

        if max_depth >= 0 and depth >= max_depth:
            break
        scale = S.prim_scale[prim]

        # Next-event estimation: one light sample, MIS-weighted against the BSDF
        if n_lights > 0 and not is_delta(mk):
            wi, li_rgb, pdf_l, t_max, delta_l = sample_light(
                S.light_kind, S.light_prim, S.light_data, S.light_cdf, S.light_pmf, S.prim_kind,
                S.prim_geo, p, uniform(key, dim), uniform(key, dim + 1), uniform(key, dim + 2))
            if pdf_l > 0.0:
                f = bsdf_eval(mk, mp, wo, wi, n)
                if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
                    origin = spawn_offset(p, n, wi, scale)
                    if t_max < math.inf:
                        # Measure from the lifted origin, and stop short of the light's surface
                        # by more than the rounding of its point (relative to its coordinates)
                        q = (p[0] + t_max * wi[0], p[1] + t_max * wi[1], p[2] + t_max * wi[2])
                        t_max -= ((origin[0] - p[0]) * wi[0] + (origin[1] - p[1]) * wi[1]
                                  + (origin[2] - p[2]) * wi[2])
                        t_max = t_max * (1.0 - SHADOW_SLACK) - SPAWN_EPSILON * max(
                            abs(q[0]), abs(q[1]), abs(q[2]))
                    if not occluded(S.bvh_lo, S.bvh_hi, S.bvh_offset, S.bvh_count, S.bvh_axis,
                                    S.prim_kind, S.prim_geo, origin, wi, t_max, stack):
                        w = 1.0 / pdf_l
                        if not delta_l:
                            w *= power_heuristic(pdf_l, bsdf_pdf(mk, mp, wo, wi, n))
                        lr += br * f[0] * li_rgb[0] * w
                        lg += bg * f[1] * li_rgb[1] * w
                        lb += bb * f[2] * li_rgb[2] * w

        # Sample the BSDF for the next direction
        wi, weight, pdf, ok = bsdf_sample(mk, mp, wo, n, uniform(key, dim + 3),
                                          uniform(key, dim + 4), uniform(key, dim + 5))
        if not ok:
            break
        br *= weight[0]
        bg *= weight[1]
        bb *= weight[2]
        if br == 0.0 and bg == 0.0 and bb == 0.0:
            break
        specular = is_delta(mk)
        prev_pdf = pdf
        prev_p = p
        depth += 1
        o = spawn_offset(p, n, wi, scale)
        d = wi

        # Russian roulette
        if depth >= RR_DEPTH:
            q = min(max(br, bg, bb), 0.95)
            if uniform(key, dim + 6) >= q:
                break
            br /= q
            bg /= q
            bb /= q
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


@parallel_kernel
def render_tile_kernel(S, width, height, seed, max_depth, stack_size, x0, y0, tile_w, tile_h,
                       sample_start, sample_count, out_sum, out_sum_sq, out_count, out_dropped):
    """Add samples [sample_start, sample_start + sample_count) of every pixel of a tile.

    Rows are shared among numba's threads; a sample whose radiance is not finite (or whose square
    overflows, |L| > 1e154) is not added but counted in ``out_dropped``, so a bad path can never
    turn a pixel into NaN or inf unnoticed.
    """
    for row in prange(tile_h):
        stack = np.empty(stack_size, np.int64)
        y = y0 + row
        for col in range(tile_w):
            x = x0 + col
            pixel = y * width + x
            sr = sg = sb = 0.0
            qr = qg = qb = 0.0
            good = 0
            bad = 0
            for s in range(sample_start, sample_start + sample_count):
                key = sample_key(seed, pixel, s)
                o, d = camera_ray(S.camera, width, height, x, y, uniform(key, 0), uniform(key, 1))
                r, g, b = trace_path(S, o, d, key, stack, max_depth)
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
