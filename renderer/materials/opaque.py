"""Effectively opaque translucent materials: the surface they look like.

When the light that enters a material comes back out within a pixel of where it went in, and none
gets through the object, subsurface transport is invisible: the material looks like a surface.
``auto`` renders such a material as the zero-radius limit of the ``diffusion`` method's separable
BSSRDF, a BRDF: the smooth Fresnel coat reflects F(θo); the rest enters and comes back out at
the same point with probability A, leaving through S_w(wi) = (1 − F(θi))/(cπ)
(renderer/materials/diffusion.py). No probe rays, no random walk.

A is not the dipole's: it is the escape probability of light that entered a semi-infinite medium
of the material's albedo, g and ior, computed by a random walk in depth only (a plane-parallel
medium is the same everywhere along the surface, so depth and direction cosine are the whole
state): ``semi_infinite_albedo``. The light enters with the cosine-weighted incidence the
separable model assumes, refracted, and is followed through scattering (HG), absorption and the
boundary's Fresnel reflection (total internal reflection included) until it leaves or is
absorbed. Checked against Chandrasekhar's H-function for an index-matched isotropic medium
(tests/renderer/materials/test_opaque.py).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from renderer.jit import kernel
from renderer.materials.fresnel import fresnel_dielectric
from renderer.materials.phase import hg_sample_cos
from renderer.rng import mix64, uniform

MAX_EVENTS = 100_000  # a walk that long (albedo 1 − 1e-5) is counted as absorbed


@kernel
def _walk(albedo, g, eta, key):
    """One walk from entry to exit; returns 1.0 if the light leaves, 0.0 if absorbed."""
    # Incidence: cosine-weighted, kept with probability 1 − F (the light that enters)
    dim = 0
    mu = 0.0
    for _ in range(1000):
        mu_o = math.sqrt(uniform(key, dim))
        f, cos_t = fresnel_dielectric(mu_o, eta)
        dim += 2
        if uniform(key, dim - 1) >= f:
            mu = cos_t
            break
    if mu <= 0.0:
        return 0.0
    z = 0.0  # depth below the surface; mu > 0 points down
    for _ in range(MAX_EVENTS):
        s = -math.log(1.0 - uniform(key, dim))
        dim += 1
        z += mu * s
        if z <= 0.0:
            # At the surface from inside: Fresnel reflection (TIR when 1/η·sin > 1) or out
            f, _ = fresnel_dielectric(-mu, 1.0 / eta)
            dim += 1
            if uniform(key, dim - 1) >= f:
                return 1.0
            z = 0.0
            mu = -mu
            continue
        dim += 3
        if uniform(key, dim - 3) >= albedo:
            return 0.0
        cos_t = hg_sample_cos(g, uniform(key, dim - 2))
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * math.pi * uniform(key, dim - 1)
        mu = mu * cos_t + math.sqrt(max(0.0, 1.0 - mu * mu)) * sin_t * math.cos(phi)
        mu = min(1.0, max(-1.0, mu))
    return 0.0


@kernel
def semi_infinite_albedo(albedo, g, eta, walks, seed):
    """(mean, standard error) of the escape probability A of light that entered."""
    total = 0.0
    for i in range(walks):
        total += _walk(albedo, g, eta, mix64(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15)
                                             + np.uint64(i)))
    mean = total / walks
    return mean, math.sqrt(max(mean * (1.0 - mean), 0.0) / walks)


OPAQUE_WALKS = 40_000  # standard error <= 0.0025 on A


LONG_WALKS = 0.9999  # above this albedo the walks get long: use the diffusion limit's law


@lru_cache(maxsize=256)
def opaque_albedo(albedo: float, g: float, ior: float) -> float:
    """A for one channel: 1 when nothing is absorbed (all the light comes back out of a
    semi-infinite medium, however long it takes), else the walk's estimate (fixed seed).

    A walk lasts ~1/(1 − albedo) events, so above ``LONG_WALKS`` the walk is run at that albedo
    and carried on by the diffusion limit's law 1 − A ∝ √(1 − albedo) (the absorbed share of a
    nearly conservative half-space; Chandrasekhar's 1 − 2√(1−ϖ)∫Hμ for the matched case): the
    cost stays bounded however close to 1 the albedo is."""
    if albedo >= 1.0:
        return 1.0
    if albedo <= 0.0:
        return 0.0
    if albedo > LONG_WALKS:
        base = opaque_albedo(LONG_WALKS, g, ior)
        return 1.0 - (1.0 - base) * math.sqrt((1.0 - albedo) / (1.0 - LONG_WALKS))
    return float(semi_infinite_albedo(float(albedo), float(g), float(ior), OPAQUE_WALKS, 1)[0])
