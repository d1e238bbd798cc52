"""Warping functions from [0,1)² to directions and points, each with its density.

Every routine here has a chi² or moment test in ``tests/renderer/test_sampling.py``. Densities are
per unit solid angle for directions and per unit area (of the unit square's image) for points.
"""

from __future__ import annotations

import math

from renderer.jit import inline_kernel, kernel

INV_PI = 1.0 / math.pi
INV_4PI = 1.0 / (4.0 * math.pi)


@kernel
def cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +z (Malley's method on a polar disk); pdf = cosθ/π."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    z = math.sqrt(max(0.0, 1.0 - u1))
    return (r * math.cos(phi), r * math.sin(phi), z)


@kernel
def cosine_hemisphere_pdf(cos_theta):
    return cos_theta * INV_PI if cos_theta > 0.0 else 0.0


@kernel
def uniform_sphere(u1, u2):
    """Uniform direction on the unit sphere; pdf = 1/(4π)."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return (r * math.cos(phi), r * math.sin(phi), z)


@kernel
def uniform_cone(u1, u2, one_minus_cos_max):
    """Uniform direction in the cone about +z with 1 − cosθmax given (exact for tiny cones).

    Passing 1 − cosθmax rather than cosθmax keeps precision for a light far away, where cosθmax
    rounds to 1 (pbrt-v4, SampleUniformCone / Sphere::Sample). pdf = 1 / (2π (1 − cosθmax)).
    """
    omc = u1 * one_minus_cos_max  # 1 - cosθ
    cos_theta = 1.0 - omc
    sin_theta = math.sqrt(max(0.0, omc * (2.0 - omc)))
    phi = 2.0 * math.pi * u2
    return (sin_theta * math.cos(phi), sin_theta * math.sin(phi), cos_theta)


@kernel
def uniform_cone_pdf(one_minus_cos_max):
    return 1.0 / (2.0 * math.pi * one_minus_cos_max)


@kernel
def phong_lobe(u1, u2, exponent):
    """Direction about +z with density ∝ cosⁿα: pdf = (n + 1)/(2π) cosⁿα (Lafortune & Willems
    1994)."""
    cos_alpha = u1 ** (1.0 / (exponent + 1.0))
    sin_alpha = math.sqrt(max(0.0, 1.0 - cos_alpha * cos_alpha))
    phi = 2.0 * math.pi * u2
    return (sin_alpha * math.cos(phi), sin_alpha * math.sin(phi), cos_alpha)


@kernel
def phong_lobe_pdf(cos_alpha, exponent):
    if cos_alpha <= 0.0:
        return 0.0
    return (exponent + 1.0) * (0.5 * INV_PI) * cos_alpha**exponent


@kernel
def uniform_triangle(u1, u2):
    """Uniform barycentrics (b1, b2) on a triangle: p = v0 + b1·e1 + b2·e2; pdf = 1/area."""
    s = math.sqrt(u1)
    return (s * (1.0 - u2), s * u2)


@kernel
def power_heuristic(pdf_a, pdf_b):
    """Veach's power heuristic (β = 2) weight for a sample drawn from strategy a."""
    a2 = pdf_a * pdf_a
    b2 = pdf_b * pdf_b
    if a2 + b2 == 0.0:
        return 0.0
    if math.isinf(a2):
        return 1.0
    return a2 / (a2 + b2)


@inline_kernel
def sample_discrete(cdf, u):
    """Index i with cdf[i-1] <= u·total < cdf[i]; ``cdf`` is an inclusive running sum. Inlined:
    ``sample_light`` picks its light with it at every vertex."""
    target = u * cdf[cdf.shape[0] - 1]
    lo = 0
    hi = cdf.shape[0] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= target:
            lo = mid + 1
        else:
            hi = mid
    return lo
