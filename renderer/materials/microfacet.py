"""The GGX (Trowbridge–Reitz) microfacet distribution shared by the rough metal and rough glass.

D(h) = α² / (π ((n·h)²(α² − 1) + 1)²); Smith's masking G1 in its separable use G1(wo)·G1(wi), as
Mitsuba 3 takes it; sampling by the distribution of visible normals (Heitz, "Sampling the GGX
Distribution of Visible Normals", JCGT 2018), whose density of h is G1(wo) max(0, wo·h) D(h) /
cos θo.
"""

from __future__ import annotations

import math

from renderer.jit import kernel


@kernel
def ggx_d(cos_h, alpha):
    """GGX normal distribution D(h) for cos θh = n·h (per unit solid angle of h)."""
    if cos_h <= 0.0:
        return 0.0
    a2 = alpha * alpha
    x = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * x * x)


@kernel
def smith_g1(cos_v, alpha):
    """Smith's masking of GGX for a direction at cos θv from the normal."""
    if cos_v <= 0.0:
        return 0.0
    tan2 = max(1.0 - cos_v * cos_v, 0.0) / (cos_v * cos_v)
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * tan2))


@kernel
def to_local(v, t, b, n):
    """World v in the frame (t, b, n)."""
    return (v[0] * t[0] + v[1] * t[1] + v[2] * t[2], v[0] * b[0] + v[1] * b[1] + v[2] * b[2],
            v[0] * n[0] + v[1] * n[1] + v[2] * n[2])


@kernel
def from_local(v, t, b, n):
    """Local v of the frame (t, b, n) in world coordinates."""
    return (v[0] * t[0] + v[1] * b[0] + v[2] * n[0], v[0] * t[1] + v[1] * b[1] + v[2] * n[1],
            v[0] * t[2] + v[1] * b[2] + v[2] * n[2])


@kernel
def ggx_visible_normal(wo, alpha, u1, u2):
    """A microfacet normal (local frame, z the surface normal) from GGX's distribution of the
    normals visible from wo (local, wo.z > 0): Heitz 2018, the hemisphere-stretch construction."""
    vx, vy, vz = alpha * wo[0], alpha * wo[1], wo[2]
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx * inv, vy * inv, vz * inv
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        il = 1.0 / math.sqrt(lensq)
        t1 = (-vy * il, vx * il, 0.0)
    else:
        t1 = (1.0, 0.0, 0.0)
    t2 = (vy * t1[2] - vz * t1[1], vz * t1[0] - vx * t1[2], vx * t1[1] - vy * t1[0])
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    nx = p1 * t1[0] + p2 * t2[0] + p3 * vx
    ny = p1 * t1[1] + p2 * t2[1] + p3 * vy
    nz = p1 * t1[2] + p2 * t2[2] + p3 * vz
    hx, hy, hz = alpha * nx, alpha * ny, max(0.0, nz)
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx * inv, hy * inv, hz * inv
