"""Dispatch on the material tag: the fixed list of material types (pbrt-v4's TaggedPointer idea).

Material kinds are small integers in ``mat_kind``, their parameters a row of ``mat_param`` whose
slots each family's file names and packs (``renderer.scene.compile`` calls its packer). All
surfaces but dielectrics are two-sided for reflection (scene format v1), so their normal is turned
to the side ``wo`` lies on before the model is asked.
"""

from __future__ import annotations

import math

from renderer.jit import inline_kernel, kernel
from renderer.materials.conductor import (
    conductor_sample,
    rough_conductor_eval,
    rough_conductor_pdf,
    rough_conductor_sample,
)
from renderer.materials.dielectric import IOR, dielectric_sample
from renderer.materials.diffuse import diffuse_eval, diffuse_pdf, diffuse_sample
from renderer.materials.diffusion import C_NORM
from renderer.materials.fresnel import fresnel_dielectric
from renderer.materials.mirror import mirror_sample
from renderer.materials.phong import phong_eval, phong_pdf, phong_sample
from renderer.materials.rough_dielectric import (
    rough_boundary_eval,
    rough_boundary_pdf,
    rough_boundary_sample,
    rough_dielectric_eval,
    rough_dielectric_pdf,
    rough_dielectric_sample,
)
from renderer.materials.translucent import ALBEDO, REFLECTED

DIFFUSE = 0
PHONG = 1
MIRROR = 2
DIELECTRIC = 3
TRANSLUCENT = 4  # method "volumetric": the boundary here, the medium in the integrator
SINGLE_SCATTER = 5  # the seed paper's method: Lambertian at the surface or one scatter inside
DIFFUSE_ENTRY = 6  # the seed student project's method: a random walk that starts at the surface
DIFFUSION = 8  # a BSSRDF: the integrator probes for the exit point (materials/diffusion.py)
DIFFUSION_EXIT = 9  # the exit vertex of DIFFUSION: S_w(wi) = (1 − F(cos θi))/(cπ)
CONDUCTOR = 10  # a smooth metal: the mirror direction weighted by the conductor Fresnel term
ROUGH_CONDUCTOR = 11  # a rough metal: GGX microfacets (renderer/materials/conductor.py)
ROUGH_DIELECTRIC = 12  # rough glass: GGX microfacets that reflect and refract
ROUGH_TRANSLUCENT = 13  # method "volumetric" behind a rough boundary: GGX as ROUGH_DIELECTRIC,
# α in translucent's BOUNDARY_ROUGHNESS slot; the medium in the integrator, as TRANSLUCENT
ROUGH_DIFFUSE_ENTRY = 14  # method "diffuse_entry" behind a rough coat: GGX reflection, and an
# entry through a GGX refraction that scatters at once (integrators/subsurface/diffuse_entry.py)
ROUGH_DIFFUSION = 15  # method "diffusion" behind a rough coat: GGX reflection, and an entry
# through the sampled GGX refraction, weighted by its transmittance, into the profile
BACKLIGHT = 7  # a Lambertian surface reflecting (1 − scale) of its albedo (slots REFLECTED), plus
# the integrator's transmitted direct light (integrators/subsurface/backlight.py), which falls
# with thickness at the per-channel rate in the SIGMA_EFF slots

N_PARAMS = 23  # the widest row: translucent's SIGMA_T slots end at 22


@kernel
def is_delta(kind):
    # A translucent material's boundary is a smooth dielectric (its volume is the integrator's)
    return (kind == MIRROR or kind == DIELECTRIC or kind == TRANSLUCENT or kind == DIFFUSE_ENTRY
            or kind == DIFFUSION or kind == CONDUCTOR)


@kernel
def rough_boundary(kind):
    """The rough boundaries of a translucent medium: a light sample may go either side (the
    shadow ray is in the medium when it goes inside)."""
    return kind == ROUGH_TRANSLUCENT or kind == ROUGH_DIFFUSE_ENTRY


@kernel
def _facing(wo, n):
    if wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2] < 0.0:
        return (-n[0], -n[1], -n[2])
    return n


@kernel
def _enters(wo, wi, n):
    """Whether (wo, wi) crosses the boundary from outside in (n the outward normal)."""
    return (wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2] > 0.0
            and wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] < 0.0)


# bsdf_eval, bsdf_pdf and bsdf_sample are inlined (LLVM, renderer/jit.py): as calls, ~20 scalar
# arguments each and three a bounce, the renders were up to 14 % slower (two `bench.ab_speed` runs;
# docs/performance.md, "Inlined by LLVM")
@inline_kernel
def bsdf_eval(kind, param, wo, wi, n):
    """f(wo, wi)·|cos θi| for the non-delta materials (zero for delta ones)."""
    if kind == ROUGH_DIELECTRIC:  # two sides that differ: the outward normal as it is
        return rough_dielectric_eval(param, wo, wi, n)
    if kind == ROUGH_TRANSLUCENT:
        return rough_boundary_eval(param, wo, wi, n)
    if kind == ROUGH_DIFFUSE_ENTRY or kind == ROUGH_DIFFUSION:
        # What enters is scattered at once, or carried to an exit: no straight path to a light
        if _enters(wo, wi, n):
            return (0.0, 0.0, 0.0)
        return rough_boundary_eval(param, wo, wi, n)
    ns = _facing(wo, n)
    if kind == DIFFUSE:
        return diffuse_eval(param, wo, wi, ns)
    if kind == SINGLE_SCATTER:
        return diffuse_eval(param[ALBEDO:], wo, wi, ns)  # its albedo, where diffuse's would be
    if kind == BACKLIGHT:
        return diffuse_eval(param[REFLECTED:], wo, wi, ns)
    if kind == DIFFUSION_EXIT:
        cos_i = wi[0] * ns[0] + wi[1] * ns[1] + wi[2] * ns[2]
        if cos_i <= 0.0:
            return (0.0, 0.0, 0.0)
        f, _ = fresnel_dielectric(cos_i, param[IOR])
        s = (1.0 - f) / (param[C_NORM] * math.pi) * cos_i
        return (s, s, s)
    if kind == PHONG:
        return phong_eval(param, wo, wi, ns)
    if kind == ROUGH_CONDUCTOR:
        return rough_conductor_eval(param, wo, wi, ns)
    return (0.0, 0.0, 0.0)


@inline_kernel
def bsdf_pdf(kind, param, wo, wi, n):
    if kind == ROUGH_DIELECTRIC:
        return rough_dielectric_pdf(param, wo, wi, n)
    if kind == ROUGH_TRANSLUCENT:
        return rough_boundary_pdf(param, wo, wi, n)
    if kind == ROUGH_DIFFUSE_ENTRY or kind == ROUGH_DIFFUSION:
        if _enters(wo, wi, n):
            return 0.0
        return rough_boundary_pdf(param, wo, wi, n)
    ns = _facing(wo, n)
    if kind == DIFFUSE or kind == SINGLE_SCATTER or kind == BACKLIGHT or kind == DIFFUSION_EXIT:
        return diffuse_pdf(param, wo, wi, ns)
    if kind == PHONG:
        return phong_pdf(param, wo, wi, ns)
    if kind == ROUGH_CONDUCTOR:
        return rough_conductor_pdf(param, wo, wi, ns)
    return 0.0


@inline_kernel
def bsdf_sample(kind, param, wo, n, uc, u1, u2):
    """(wi, f·|cos|/pdf, pdf, ok); pdf is 0 for the delta materials."""
    if kind == DIELECTRIC or kind == TRANSLUCENT or kind == DIFFUSE_ENTRY or kind == DIFFUSION:
        # all keep the boundary's ior in dielectric's IOR slot
        wi, w = dielectric_sample(param, wo, n, uc)
        return wi, (w, w, w), 0.0, True
    if kind == ROUGH_DIELECTRIC:
        return rough_dielectric_sample(param, wo, n, uc, u1, u2)
    if kind == ROUGH_TRANSLUCENT or kind == ROUGH_DIFFUSE_ENTRY or kind == ROUGH_DIFFUSION:
        return rough_boundary_sample(param, wo, n, uc, u1, u2)
    ns = _facing(wo, n)
    if kind == MIRROR:
        wi, weight = mirror_sample(param, wo, ns)
        return wi, weight, 0.0, True
    if kind == CONDUCTOR:
        wi, weight = conductor_sample(param, wo, ns)
        return wi, weight, 0.0, True
    if kind == ROUGH_CONDUCTOR:
        return rough_conductor_sample(param, wo, ns, u1, u2)
    if kind == PHONG:
        return phong_sample(param, wo, ns, uc, u1, u2)
    if kind == SINGLE_SCATTER:
        return diffuse_sample(param[ALBEDO:], wo, ns, u1, u2)
    if kind == BACKLIGHT:
        return diffuse_sample(param[REFLECTED:], wo, ns, u1, u2)
    if kind == DIFFUSION_EXIT:
        wi, _, pdf, ok = diffuse_sample(param, wo, ns, u1, u2)
        f, _ = fresnel_dielectric(max(0.0, wi[0] * ns[0] + wi[1] * ns[1] + wi[2] * ns[2]),
                                  param[IOR])
        w = (1.0 - f) / param[C_NORM]  # S_w·cos/pdf = (1 − F)/(cπ)·cos / (cos/π)
        return wi, (w, w, w), pdf, ok
    return diffuse_sample(param, wo, ns, u1, u2)
