"""Arbitrary output variables (AOVs): the extra layers a scene's ``film.aovs`` asks for.

===========  ========  ==========================================================================
Name         Channels  Meaning
===========  ========  ==========================================================================
``albedo``   R, G, B   reflectance of the first vertex that is not a perfect mirror, smooth metal
                       or smooth glass (see below), times the colour of the mirrors on the way
``normal``   X, Y, Z   that vertex's shading normal in world space, turned towards the viewer
``depth``    Z         distance along the camera's viewing axis to the first surface it sees
                       (smooth glass included); ``inf`` where the ray leaves the scene
``variance`` R, G, B   the estimated variance of each pixel's mean (``SampleBuffer``), what the
                       adaptive rule weighs
``spp``      Y         samples in each pixel's mean
===========  ========  ==========================================================================

Albedo, normal and depth are traced by their own small kernel (``aov_kernel``): ``spp`` jittered
primary rays a pixel, each followed through perfect mirrors and smooth metals (the reflection,
its albedo multiplied by the reflectance) and smooth dielectrics (the refracted branch, reflected
only under total internal reflection, tinted by the glass's absorption), up to
``MAX_SPECULAR`` such events. This is what Intel Open Image Denoise asks of its auxiliary images:
the albedo and normal of the first diffuse-like surface, so that a glass sphere's albedo shows
what lies behind it. At the vertex where the path stops the albedo is:

- ``diffuse``: its (possibly textured) albedo; ``phong``: diffuse + specular, at most 1;
- a rough metal: its specular tint times its Fresnel reflectance at the viewing angle;
- rough glass: 1 (white: it changes the colour of nothing);
- ``translucent`` (every method): the medium's single-scattering albedo σs/σt at the entry point,
  on the object's surface. The light under the surface is not followed: the colour of a
  translucent object is its medium's, and its surface is where the eye sees it.

Albedo and normal are the means over the samples (a ray that leaves the scene adds 0), so edges
are antialiased as in the image; depth is the mean over the samples that hit something.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.geometry.bvh import intersect_closest, traversal_stack
from renderer.geometry.shapes import spawn_offset
from renderer.integrators.path import camera_ray, surface_vertex
from renderer.jit import inline_kernel, kernel, run_chunks
from renderer.materials.bsdf import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    N_PARAMS,
    PHONG,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
)
from renderer.materials.conductor import ETA, SPECULAR, K, conductor_sample, fresnel_conductor
from renderer.materials.dielectric import IOR, absorbed
from renderer.materials.diffuse import ALBEDO as DIFFUSE_ALBEDO
from renderer.materials.fresnel import fresnel_dielectric, reflect, refract
from renderer.materials.mirror import mirror_sample
from renderer.materials.phong import KD, KS
from renderer.materials.translucent import ALBEDO
from renderer.rng import sample_key, uniform

AOV_NAMES = ("albedo", "normal", "depth", "variance", "spp")
# Channels of each layer in a multi-layer EXR (renderer.film.image_io.encode_exr_layers)
AOV_CHANNELS = {"albedo": ("R", "G", "B"), "normal": ("X", "Y", "Z"), "depth": ("Z",),
                "variance": ("R", "G", "B"), "spp": ("Y",)}
# Mirrors and glass followed before a path gives up (albedo 0): two facing mirrors
MAX_SPECULAR = 32
# Keys the AOV rays' jitter apart from the image's samples (any odd constant)
AOV_SALT = np.uint64(0x41F0_5EED_A0F5_0001)


@kernel
def _stop_albedo(mk, mp, cos_o):
    """The albedo of the vertex where an AOV path stops (see the module's list)."""
    if mk == DIFFUSE:
        return mp[DIFFUSE_ALBEDO], mp[DIFFUSE_ALBEDO + 1], mp[DIFFUSE_ALBEDO + 2]
    if mk == PHONG:
        return (min(1.0, mp[KD] + mp[KS]), min(1.0, mp[KD + 1] + mp[KS + 1]),
                min(1.0, mp[KD + 2] + mp[KS + 2]))
    if mk == ROUGH_CONDUCTOR:
        c = abs(cos_o)
        return (mp[SPECULAR] * fresnel_conductor(c, mp[ETA], mp[K]),
                mp[SPECULAR + 1] * fresnel_conductor(c, mp[ETA + 1], mp[K + 1]),
                mp[SPECULAR + 2] * fresnel_conductor(c, mp[ETA + 2], mp[K + 2]))
    if mk == ROUGH_DIELECTRIC:
        return 1.0, 1.0, 1.0
    # every translucent method, smooth or rough coat: the medium's single-scattering albedo
    return mp[ALBEDO], mp[ALBEDO + 1], mp[ALBEDO + 2]


@inline_kernel
def _aov_pixel(S, width, height, seed, x, y, spp, stack, scratch):
    """(albedo, normal, depth sum, hits) of pixel (x, y) over ``spp`` jittered rays."""
    ar = ag = ab = 0.0
    nx = ny = nz = 0.0
    depth_sum = 0.0
    hits = 0
    fw = (S.camera[3], S.camera[4], S.camera[5])
    pixel = y * width + x
    for s in range(spp):
        key = sample_key(np.uint64(seed) ^ AOV_SALT, pixel, s)
        o, d = camera_ray(S.camera, width, height, x, y, uniform(key, 0), uniform(key, 1))
        tr = tg = tb = 1.0  # the colour of the mirrors and glass on the way
        first = True
        for _ in range(MAX_SPECULAR + 1):
            t, prim, u, v = intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count,
                                              S.flat, S.prim_kind, S.prim_geo, o, d, math.inf,
                                              stack)
            if prim < 0:
                break
            kind, geo, mat = S.prim_kind[prim], S.prim_geo[prim], S.prim_material[prim]
            mk, scale = S.mat_kind[mat], S.prim_scale[prim]
            p, n, ns, textured = surface_vertex(S, kind, geo, prim, mat, mk, o, d, t, u, v,
                                                scratch)
            mp = scratch if textured else S.mat_param[mat]
            if first:
                # the first surface seen: its distance along the viewing axis
                depth_sum += t * (d[0] * fw[0] + d[1] * fw[1] + d[2] * fw[2])
                hits += 1
                first = False
            wo = (-d[0], -d[1], -d[2])
            cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
            if mk == MIRROR or mk == CONDUCTOR or mk == DIELECTRIC:
                # Perfect specular: follow it (a smooth dielectric's refracted branch)
                facing = ns if wo[0] * ns[0] + wo[1] * ns[1] + wo[2] * ns[2] >= 0.0 else (
                    -ns[0], -ns[1], -ns[2])
                if mk == MIRROR:
                    wi, w = mirror_sample(mp, wo, facing)
                    tr, tg, tb = tr * w[0], tg * w[1], tb * w[2]
                elif mk == CONDUCTOR:
                    wi, w = conductor_sample(mp, wo, facing)
                    tr, tg, tb = tr * w[0], tg * w[1], tb * w[2]
                else:
                    if cos_o < 0.0:  # Beer–Lambert through the glass just crossed
                        tr, tg, tb = absorbed(mp, t, tr, tg, tb)
                    eta, nn, c = mp[IOR], n, cos_o
                    if cos_o < 0.0:
                        eta, nn, c = 1.0 / mp[IOR], (-n[0], -n[1], -n[2]), -cos_o
                    f, cos_t = fresnel_dielectric(c, eta)
                    wi = reflect(wo, nn) if f >= 1.0 else refract(wo, nn, eta, c, cos_t)
                o = spawn_offset(p, n, wi, scale)
                d = wi
                continue
            # The first vertex that is not perfectly specular: its albedo and normal
            a = _stop_albedo(mk, mp, cos_o)
            ar, ag, ab = ar + tr * a[0], ag + tg * a[1], ab + tb * a[2]
            sgn = 1.0 if wo[0] * ns[0] + wo[1] * ns[1] + wo[2] * ns[2] >= 0.0 else -1.0
            nx, ny, nz = nx + sgn * ns[0], ny + sgn * ns[1], nz + sgn * ns[2]
            break
    return ar, ag, ab, nx, ny, nz, depth_sum, hits


@kernel
def aov_rows(S, width, height, seed, spp, first_row, row_step, out_albedo, out_normal, out_depth,
             stack, scratch):
    """Fill the albedo (h, w, 3), normal (h, w, 3) and depth (h, w) of rows ``first_row``,
    ``first_row + row_step``, … of the frame (one thread's share; ``stack`` a
    ``traversal_stack``, ``scratch`` N_PARAMS, owned by the caller)."""
    for y in range(first_row, height, row_step):
        for x in range(width):
            ar, ag, ab, nx, ny, nz, dsum, hits = _aov_pixel(S, width, height, seed, x, y, spp,
                                                            stack, scratch)
            out_albedo[y, x, 0] = ar / spp
            out_albedo[y, x, 1] = ag / spp
            out_albedo[y, x, 2] = ab / spp
            out_normal[y, x, 0] = nx / spp
            out_normal[y, x, 1] = ny / spp
            out_normal[y, x, 2] = nz / spp
            out_depth[y, x] = dsum / hits if hits > 0 else math.inf


def aov_kernel(S, width, height, seed, spp, stack_size, out_albedo, out_normal, out_depth,
               n_threads):
    """Fill the albedo (h, w, 3), normal (h, w, 3) and depth (h, w) of the whole frame, its rows
    dealt out in turn to ``n_threads`` threads (as ``render_tile_kernel`` does)."""
    n_chunks = max(1, min(height, n_threads))

    def chunk(c: int) -> None:
        aov_rows(S, width, height, seed, spp, c, n_chunks, out_albedo, out_normal, out_depth,
                 traversal_stack(stack_size), np.zeros(N_PARAMS))

    run_chunks(chunk, n_chunks)


def render_aovs(compiled, names, spp: int = 4, threads: int | None = None) -> dict:
    """The traced AOVs among ``names`` (``albedo``, ``normal``, ``depth``) of a compiled scene,
    each an (h, w, C) float32 array; other names are left to ``buffer_aovs``."""
    import numba

    wanted = [n for n in names if n in ("albedo", "normal", "depth")]
    if not wanted:
        return {}
    if spp < 1:
        raise ValueError(f"AOV spp must be >= 1, not {spp}")
    h, w = compiled.height, compiled.width
    albedo = np.zeros((h, w, 3))
    normal = np.zeros((h, w, 3))
    depth = np.zeros((h, w))
    n_threads = threads or numba.get_num_threads()
    aov_kernel(compiled.arrays, w, h, compiled.seed, spp, compiled.stack_size, albedo, normal,
               depth, n_threads)
    layers = {"albedo": albedo, "normal": normal, "depth": depth[..., None]}
    return {n: layers[n].astype(np.float32) for n in wanted}


def buffer_aovs(buffer, names) -> dict:
    """The AOVs among ``names`` that a frame's ``SampleBuffer`` holds: ``variance`` (h, w, 3)
    of each pixel's mean, ``spp`` (h, w, 1) its sample count."""
    out = {}
    if "variance" in names:
        out["variance"] = buffer.variance_of_mean().astype(np.float32)
    if "spp" in names:
        out["spp"] = buffer.count[..., None].astype(np.float32)
    return out


def frame_aovs(compiled, buffer, names, spp: int = 4, threads: int | None = None) -> dict:
    """Every AOV of ``names`` in the order asked: traced ones and the buffer's."""
    layers = {**render_aovs(compiled, names, spp, threads), **buffer_aovs(buffer, names)}
    return {n: layers[n] for n in dict.fromkeys(names)}
