"""Unidirectional path tracing with next-event estimation and multiple importance sampling.

The structure is pbrt-v4's PathIntegrator::Li. At every non-delta vertex one light sample
(``renderer.integrators.direct``) and one BSDF sample are taken; where both strategies can reach
the same light (area lights and the background), each is weighted by Veach's power heuristic, and
delta lights (point, directional) take the light sample alone. Paths are ended by Russian roulette
(``renderer.integrators.roulette``), so an unlimited ``max_depth`` (-1) stays unbiased.

``max_depth`` counts scattering events (scene format v1): 0 shows only what the camera sees
directly, 1 adds direct lighting. Mitsuba's ``max_depth`` counts path segments, one more.

The translucent methods act at the vertices where their light goes under the surface, each from
its own file in ``renderer/integrators/subsurface/``: the medium walk of ``volumetric`` (and of
``single_scatter`` inside), the straight crossings of ``single_scatter``'s surface, the exit
probe of ``diffusion``, the entry scattering and separate direct light of ``diffuse_entry``, the
transmitted term of ``backlight`` (in the light sample). Random numbers: ``renderer.integrators.
sampler`` (which dimension each decision of a path uses).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.environment import direction_to_uv, environment_pdf, environment_radiance
from renderer.geometry.bvh import intersect_closest, traversal_stack
from renderer.geometry.shapes import (
    interpolated_normal,
    intersect_sphere,
    spawn_offset,
    surface_point,
)
from renderer.integrators.direct import surface_direct
from renderer.integrators.roulette import RR_MAX, roulette
from renderer.integrators.sampler import (
    DIMS_PER_BOUNCE,
    PIXEL_SEED_SALT,
    SOBOL_BLOCKS,
    draw,
)
from renderer.integrators.subsurface.diffuse_entry import entry_direct, entry_scatter
from renderer.integrators.subsurface.diffusion import diffusion_exit
from renderer.integrators.subsurface.single_scatter import after_the_event, passes_straight
from renderer.integrators.subsurface.volumetric import ENDED, SCATTERED, medium_segment
from renderer.jit import block, claim_row, inline_kernel, kernel, run_chunks
from renderer.lights import ENVIRONMENT, area_light_pdf
from renderer.materials.bsdf import (
    DIELECTRIC,
    DIFFUSE_ENTRY,
    DIFFUSION,
    N_PARAMS,
    ROUGH_DIELECTRIC,
    ROUGH_DIFFUSE_ENTRY,
    ROUGH_DIFFUSION,
    ROUGH_TRANSLUCENT,
    SINGLE_SCATTER,
    TRANSLUCENT,
    is_delta,
    rough_boundary,
)
from renderer.materials.dielectric import absorbed
from renderer.materials.shading import bent_normal, shaded_sample, uses_shading_normal
from renderer.materials.translucent import DIRECT_LIGHT, IOR
from renderer.rng import mix64, sample_key, sobol_block_seeds, sobol_value, uniform
from renderer.sampling import INV_4PI, power_heuristic
from renderer.textures import textured_row

# A guard against a path that never ends (a ray trapped between two perfect mirrors with
# roulette surviving at 0.95 still ends, but only with probability one). Every scattering event
# past RR_DEPTH survives with probability ≤ 0.95, so a path of 2¹⁸ segments (scattering events
# and index-matched boundary crossings) has probability ~10⁻¹⁰⁰⁰: the cap never biases an image.
MAX_SEGMENTS = 1 << 18


@block
def null_boundary(S, mk, mp, mat, cos_o, medium, single_done, skip_emission, key, dim, sidx, sob):
    """Whether the ray crosses the surface of material ``mat`` straight on, with no scattering
    event (Mitsuba's null BSDF does not count towards depth either): an index-matched boundary
    (volumetric), and single_scatter's surface going in to scatter at most once, or out. Returns
    (crossed, medium, single_done, skip_emission) for the segment after the surface."""
    if mk == TRANSLUCENT and mp[IOR] == 1.0:
        return True, mat if cos_o > 0.0 else -1, single_done, skip_emission
    if mk == SINGLE_SCATTER and passes_straight(S, mp, cos_o, key, dim, sidx, sob):
        return True, mat if cos_o > 0.0 else -1, False, False
    return False, medium, single_done, False


@block
def surface_vertex(S, kind, geo, prim, mat, mk, o, d, t, u, v, scratch):
    """A hit's point, outward geometric normal n, shading normal ns (a mesh's interpolated
    normals bent for the view, ``renderer.materials.shading``; else n itself), and whether the
    material is textured (its row at the hit is then in ``scratch``, ``renderer.textures``)."""
    p, n = surface_point(kind, geo, o, d, t, u, v)
    textured = textured_row(S, mat, kind, prim, u, v, n, scratch)
    ns = n
    if S.prim_normal.shape[0] > 0 and uses_shading_normal(mk):
        ns_i = interpolated_normal(S.prim_normal, kind, prim, u, v, n)
        if ns_i[0] != n[0] or ns_i[1] != n[1] or ns_i[2] != n[2]:
            ns = bent_normal((-d[0], -d[1], -d[2]), n, ns_i)
    return p, n, ns, textured


@inline_kernel
def escaped_radiance(S, env, d):
    """What a ray leaving the scene along d sees of light ``env`` (the constant background or the
    environment image): (radiance, the solid-angle density of its light sample for d, before the
    light's choice probability)."""
    if S.light_kind[env] == ENVIRONMENT:
        u_env, v_env, _ = direction_to_uv(S.env_rotation, d)
        le = environment_radiance(S.env_image, u_env, v_env)
        return le, environment_pdf(S.env_image, S.env_marginal, S.env_conditional,
                                   S.env_rotation, d)
    return (S.background[0], S.background[1], S.background[2]), INV_4PI


@block
def closest_surface(S, o, d, medium, medium_prim, stack):
    """(t, prim, u, v) of the closest surface along the ray. In a medium entered through a
    sphere that no other surface enters (``prim_alone``), that sphere's: the t the whole scene's
    query finds, for one ``intersect_sphere`` (Cycles' random walk likewise intersects only its
    own object)."""
    if medium >= 0 and medium_prim >= 0 and S.prim_alone[medium_prim] != 0 \
            and S.prim_material[medium_prim] == medium:
        t = intersect_sphere(o, d, S.prim_geo[medium_prim])[0]
        if t < math.inf:
            return t, medium_prim, 0.0, 0.0
    return intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat, S.prim_kind,
                             S.prim_geo, o, d, math.inf, stack)


@inline_kernel
def trace_path(S, o, d, key, stack, max_depth, sidx, sob, scratch):
    """Radiance arriving at o from direction −d along one sampled path, and the path's segments
    (rays traced to the closest surface: its cost, which adaptive sampling weighs). S is
    ``SceneArrays``; ``sidx`` (the sample's index) and ``sob`` (its pixel's sequence seeds) feed
    the sobol sampler's first vertices (``draw``); ``scratch`` (N_PARAMS) holds a textured
    material's row at the current vertex (``textured_row``)."""
    lr = lg = lb = 0.0  # radiance gathered so far
    br = bg = bb = 1.0  # throughput β
    depth = 0  # scattering events so far
    # True when the previous vertex took no light sample (the camera, a delta BSDF, a medium
    # behind a refracting boundary): an emitter found next then counts in full, without MIS.
    unweighted, prev_pdf, prev_p = True, 0.0, o
    medium = -1  # material whose medium the ray travels in (−1: vacuum)
    medium_prim = -1  # the primitive the ray last crossed into ``medium`` at (closest_surface)
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
    segments = 0
    for _ in range(MAX_SEGMENTS):
        segments += 1
        # The closest surface along the ray
        t, prim, u, v = closest_surface(S, o, d, medium, medium_prim, stack)

        # Inside a medium: single_scatter's after its one event only attenuates; otherwise a free
        # flight may end at a scattering event before the surface (volumetric, single_scatter)
        if medium >= 0 and single_done:
            br, bg, bb = after_the_event(S, medium, t, br, bg, bb)
        elif medium >= 0:
            (event, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb, br, bg,
             bb) = medium_segment(S, medium, t, o, d, depth, unweighted, prev_pdf, prev_p,
                                  single_done, lr, lg, lb, br, bg, bb, eta_scale, max_depth, key,
                                  dim, sidx, sob, stack)
            if event == ENDED:
                break
            if event == SCATTERED:
                dim += DIMS_PER_BOUNCE
                continue

        # Escaped: the constant background or the environment image, MIS-weighted against its
        # light sample
        if prim < 0:
            if env >= 0 and not skip_emission:
                le, pdf_env = escaped_radiance(S, env, d)
                w = 1.0
                if not unweighted:
                    w = power_heuristic(prev_pdf, S.light_pmf[env] * pdf_env)
                lr, lg, lb = lr + br * le[0] * w, lg + bg * le[1] * w, lb + bb * le[2] * w
            break

        # The surface point and its material
        kind, geo, mat = S.prim_kind[prim], S.prim_geo[prim], S.prim_material[prim]
        mk, scale = S.mat_kind[mat], S.prim_scale[prim]
        p, n, ns, textured = surface_vertex(S, kind, geo, prim, mat, mk, o, d, t, u, v, scratch)
        mp = scratch if textured else S.mat_param[mat]
        wo = (-d[0], -d[1], -d[2])
        cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]

        # Beer–Lambert: a ray reaching a dielectric from inside crossed t of its medium
        if (mk == DIELECTRIC or mk == ROUGH_DIELECTRIC) and cos_o < 0.0:
            br, bg, bb = absorbed(mp, t, br, bg, bb)

        # Emission from an area light's front side, MIS-weighted against its light sample
        li = S.prim_light[prim]
        if li >= 0 and cos_o > 0.0 and not skip_emission:
            w = 1.0
            if not unweighted:
                w = power_heuristic(prev_pdf,
                                    area_light_pdf(S.light_pmf, li, kind, geo, prev_p, p, n))
            lr, lg, lb = (lr + br * S.light_data[li, 3] * w, lg + bg * S.light_data[li, 4] * w,
                          lb + bb * S.light_data[li, 5] * w)

        # Straight crossings, no scattering event (null_boundary); a diffusion material reached
        # from inside (the camera in the object) is left straight too, past the depth check
        crossed, medium, single_done, skip_emission = null_boundary(
            S, mk, mp, mat, cos_o, medium, single_done, skip_emission, key, dim, sidx, sob)
        medium_prim = prim if crossed else medium_prim
        if not crossed and max_depth >= 0 and depth >= max_depth:
            break
        diffusion = mk == DIFFUSION or mk == ROUGH_DIFFUSION
        if crossed or (diffusion and cos_o <= 0.0):
            o = spawn_offset(p, n, d, scale)
            dim += DIMS_PER_BOUNCE
            continue

        # Under the surface (diffusion): the coat reflects (a rough one lit there), or the path
        # goes on from the exit
        if diffusion:
            ended, p, n, wo, mk, scale, br, bg, bb, depth, dim, lr, lg, lb = diffusion_exit(
                S, mat, mp, prim, p, n, wo, cos_o, scale, medium, null_media, br, bg, bb, lr, lg,
                lb, depth, max_depth, key, dim, sidx, sob, stack)
            if ended:
                break
            ns = n  # the exit point's: diffusion keeps the geometric normal

        # Next-event estimation: one light sample, MIS-weighted against the BSDF (backlight:
        # the light from behind comes through; a rough diffusion coat's was taken before it
        # chose to reflect)
        delta = is_delta(mk)
        if n_lights > 0 and not delta and mk != ROUGH_DIFFUSION:
            # (a rough translucent boundary's light sample may go either side: its medium)
            c = surface_direct(S, mk, mp, p, n, ns, wo, scale, mat if rough_boundary(mk)
                               else medium, null_media, br, bg, bb, key, dim, sidx, sob, stack)
            lr, lg, lb = lr + c[0], lg + c[1], lb + c[2]
        if mk == DIFFUSE_ENTRY and mp[DIRECT_LIGHT] > 0.0 and cos_o > 0.0 and n_lights > 0:
            c = entry_direct(S, mp, p, n, cos_o, scale, null_media, br, bg, bb, key, dim, sidx,
                             sob, stack)
            lr, lg, lb = lr + c[0], lg + c[1], lb + c[2]

        # The BSDF's sample for the next direction (diffuse_entry: its entry scattering)
        wi, weight, pdf, ok = shaded_sample(mk, mp, wo, n, ns, draw(S, key, dim, 3, sidx, sob),
                                            draw(S, key, dim, 4, sidx, sob),
                                            draw(S, key, dim, 5, sidx, sob))
        if ok and (mk == DIFFUSE_ENTRY or mk == ROUGH_DIFFUSE_ENTRY):
            ok, wi, weight, skip_emission, eta_scale = entry_scatter(
                S, mp, n, cos_o, wi, weight, eta_scale, key, dim, sidx, sob)
        if not ok:
            break
        br, bg, bb = br * weight[0], bg * weight[1], bb * weight[2]
        if br == 0.0 and bg == 0.0 and bb == 0.0:
            break
        if (mk == TRANSLUCENT or mk == DIFFUSE_ENTRY or mk == ROUGH_TRANSLUCENT
                or mk == ROUGH_DIFFUSE_ENTRY):
            # Refracted in or out, or reflected: the side wi leaves on decides the medium
            medium = mat if wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0 else -1
            medium_prim = prim
        if (mk == DIELECTRIC or mk == TRANSLUCENT) and weight[0] != 1.0:
            eta_scale /= weight[0]  # a refraction: the weight was (η_i/η_t)²
        elif (mk == ROUGH_DIELECTRIC or mk == ROUGH_TRANSLUCENT) and (cos_o > 0.0) != (
                wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0.0):
            eta_scale *= mp[IOR] * mp[IOR] if cos_o > 0.0 else 1.0 / (mp[IOR] * mp[IOR])
        if mk == ROUGH_DIFFUSE_ENTRY and cos_o > 0.0 and medium == mat:
            delta = True  # entered: the sampled direction was replaced by the entry scattering
        unweighted, prev_pdf, prev_p, depth = delta, pdf, p, depth + 1
        o, d = spawn_offset(p, n, wi, scale), wi

        # Russian roulette
        alive, br, bg, bb = roulette(S, br, bg, bb, eta_scale, RR_MAX, depth, key, dim, sidx, sob)
        if not alive:
            break
        dim += DIMS_PER_BOUNCE
    return lr, lg, lb, segments


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


@inline_kernel
def pixel_sequence_seeds(S, seed, pixel, sob):
    """Under the sobol sampler, fill ``sob`` with the pixel's sequence scrambles (a hash apart
    from every sample's key); the independent sampler needs none."""
    if S.sampler[0] == 1:
        sobol_block_seeds(mix64(sample_key(seed, pixel, 0) ^ PIXEL_SEED_SALT), sob)


@inline_kernel
def camera_sample(S, width, height, x, y, s, key, sob):
    """The camera ray of sample s of pixel (x, y), its jitter dimensions 0 and 1: the
    independent sampler's from the sample's ``key``, the sobol sampler's from its pixel's
    sequence seeds ``sob`` (``sobol_block_seeds``)."""
    if S.sampler[0] == 1:
        jx = sobol_value(s, sob[0, 0], sob[0, 1], 0)
        jy = sobol_value(s, sob[0, 0], sob[0, 2], 1)
    else:
        jx = uniform(key, 0)
        jy = uniform(key, 1)
    return camera_ray(S.camera, width, height, x, y, jx, jy)


@kernel
def render_rows(S, width, height, seed, max_depth, x0, y0, tile_w, tile_h, next_row,
                sample_start, sample_count, active, out_sum, out_sum_sq, out_count, out_dropped,
                out_segments, stack, sob, scratch):
    """Add the samples of the rows of a tile this thread claims (``claim_row`` on ``next_row``,
    int64 (1,), which the pass's threads share), one after the other until none is left: one
    thread's share of ``render_tile_kernel``. ``stack`` is a ``traversal_stack``, ``sob``
    (SOBOL_BLOCKS, 3) scratch for the sobol sampler's seeds of a pixel, ``scratch`` (N_PARAMS)
    for a textured material's row; the caller owns them (this kernel runs without numba's
    runtime)."""
    while True:
        row = claim_row(next_row)
        if row >= tile_h:
            break
        y = y0 + row
        for col in range(tile_w):
            n_samples = min(sample_count, active[row, col])
            if n_samples <= 0:
                continue
            x = x0 + col
            pixel = y * width + x
            pixel_sequence_seeds(S, seed, pixel, sob)
            sr = sg = sb = 0.0
            qr = qg = qb = 0.0
            good = 0
            bad = 0
            segments = 0
            for s in range(sample_start, sample_start + n_samples):
                key = sample_key(seed, pixel, s)
                o, d = camera_sample(S, width, height, x, y, s, key, sob)
                r, g, b, n_seg = trace_path(S, o, d, key, stack, max_depth, s, sob, scratch)
                segments += n_seg
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
            out_segments[row, col] += segments


def render_tile_kernel(S, width, height, seed, max_depth, stack_size, x0, y0, tile_w, tile_h,
                       sample_start, sample_count, active, out_sum, out_sum_sq, out_count,
                       out_dropped, out_segments, n_threads):
    """Add samples [sample_start, sample_start + sample_count) of every pixel of a tile.

    Rows are shared among ``n_threads`` threads, each running ``render_rows`` (which releases
    the GIL) with a traversal stack and scratch of its own; a sample whose radiance is not
    finite (or whose square overflows, |L| > 1e154) is not added but counted in
    ``out_dropped``, so a bad path can never turn a pixel into NaN or inf unnoticed. ``active``
    (tile_h, tile_w) int32 is how many of the samples each pixel takes (the first
    min(sample_count, active) of the range; adaptive sampling: 0 for a pixel that takes none).
    """
    # Each thread claims the next row when it has finished one (claim_row), rather than taking
    # a fixed share: rows c, c + n, c + 2n, … left one of two threads 15 % behind the other on
    # the translucent sphere at 64×48 (scratch), and n contiguous blocks would leave the others
    # idle where one holds the costly part of the frame. Threads of this
    # process (renderer.jit.run_chunks), not a prange on numba's pool: a parallel kernel is one
    # more module that links in and optimizes trace_path's code again, a quarter of a cold
    # compile (docs/performance.md, "Start-up: JIT compile and cache")
    n_chunks = max(1, min(tile_h, n_threads))

    next_row = np.zeros(1, np.int64)

    def chunk(c: int) -> None:
        render_rows(S, width, height, seed, max_depth, x0, y0, tile_w, tile_h, next_row,
                    sample_start, sample_count, active, out_sum, out_sum_sq, out_count,
                    out_dropped, out_segments, traversal_stack(stack_size),
                    np.zeros((SOBOL_BLOCKS, 3), np.uint64), np.zeros(N_PARAMS))

    run_chunks(chunk, n_chunks)
