"""Ray–shape intersection for the three primitive kinds every object compiles to.

A primitive is a row of ``prim_geo`` (float64, 9 columns):

- ``SPHERE``: centre (0:3), radius (3);
- ``QUAD``: origin (0:3), edge1 (3:6), edge2 (6:9) — the parallelogram origin + s·e1 + t·e2;
- ``TRIANGLE``: v0 (0:3), e1 = v1 − v0 (3:6), e2 = v2 − v0 (6:9).

Boxes become six quads with outward normals, meshes become triangles. Each routine returns
(t, u, v) with t = inf on a miss; (u, v) are the surface parameters the hit point is rebuilt from.
Rays start off the surface (see ``spawn_offset``), so every routine accepts any t > 0.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.jit import alloc_kernel, inline_kernel, kernel

SPHERE = 0
QUAD = 1
TRIANGLE = 2

INF = np.inf


@kernel
def sphere_roots(o, d, geo):
    """Both distances (t0 ≤ t1) at which the line o + t·d meets a sphere, of any sign; (inf, inf)
    when it does not. d need not be normalized.

    The discriminant is computed as r² − |f − (f·d̂)d̂|² rather than b² − c, which keeps precision
    for rays that start far from a small sphere (Haines et al., "Precision Improvements for
    Ray/Sphere Intersection", Ray Tracing Gems, ch. 7).
    """
    cx, cy, cz, r = geo[0], geo[1], geo[2], geo[3]
    fx, fy, fz = o[0] - cx, o[1] - cy, o[2] - cz
    dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = -(fx * d[0] + fy * d[1] + fz * d[2])  # b' = -f·d
    # l = f + (b'/dd) d : the vector from the centre to the ray's closest approach
    s = b / dd
    lx, ly, lz = fx + s * d[0], fy + s * d[1], fz + s * d[2]
    disc = dd * (r * r - (lx * lx + ly * ly + lz * lz))
    if disc < 0.0:
        return INF, INF
    c = fx * fx + fy * fy + fz * fz - r * r
    q = b + math.copysign(math.sqrt(disc), b)
    if q == 0.0:
        return INF, INF
    t0 = c / q
    t1 = q / dd
    if t0 > t1:
        t0, t1 = t1, t0
    return t0, t1


@kernel
def intersect_sphere(o, d, geo):
    """Nearest t > 0 on a sphere (``sphere_roots``); d need not be normalized."""
    t0, t1 = sphere_roots(o, d, geo)
    if t0 > 0.0:
        return t0, 0.0, 0.0
    if t1 > 0.0:
        return t1, 0.0, 0.0
    return INF, 0.0, 0.0


@kernel
def intersect_parallelogram(o, d, geo, is_triangle):
    """Möller–Trumbore for a triangle (u, v ≥ 0, u + v ≤ 1) or a parallelogram (u, v ∈ [0, 1]).

    Every quantity is computed and the hit decided by one test at the end (the ``|`` do not
    short-circuit): a ray misses most primitives it is tested against, and in no predictable
    order, so early exits cost more in mispredicted branches than the arithmetic they skip.
    A zero determinant (a ray in the plane) gives inf or NaN in u, v and t, which the test rejects
    through ``det == 0`` as the early exit did.
    """
    e1x, e1y, e1z = geo[3], geo[4], geo[5]
    e2x, e2y, e2z = geo[6], geo[7], geo[8]
    # p = d × e2
    px = d[1] * e2z - d[2] * e2y
    py = d[2] * e2x - d[0] * e2z
    pz = d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    inv_det = 1.0 / det
    tx, ty, tz = o[0] - geo[0], o[1] - geo[1], o[2] - geo[2]
    u = (tx * px + ty * py + tz * pz) * inv_det
    # q = t × e1
    qx = ty * e1z - tz * e1y
    qy = tz * e1x - tx * e1z
    qz = tx * e1y - ty * e1x
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv_det
    t = (e2x * qx + e2y * qy + e2z * qz) * inv_det
    v_far = u + v if is_triangle else v
    miss = ((det == 0.0) | (u < 0.0) | (u > 1.0) | (v < 0.0) | (v_far > 1.0)
            | (not t > 0.0))
    if miss:
        return INF, 0.0, 0.0
    return t, u, v


@inline_kernel
def intersect_prim(kind, o, d, geo):
    if kind == SPHERE:
        return intersect_sphere(o, d, geo)
    return intersect_parallelogram(o, d, geo, kind == TRIANGLE)


@kernel
def surface_point(kind, geo, o, d, t, u, v):
    """Hit point and outward geometric normal (unit) of a primitive hit at (t, u, v).

    Spheres reproject the point onto the surface, and planar shapes rebuild it from (u, v): both are
    exact to a few ulps of the shape's coordinates, whatever the ray's length, so the offset in
    ``spawn_offset`` can stay tiny.
    """
    if kind == SPHERE:
        px = o[0] + t * d[0] - geo[0]
        py = o[1] + t * d[1] - geo[1]
        pz = o[2] + t * d[2] - geo[2]
        inv = 1.0 / math.sqrt(px * px + py * py + pz * pz)
        nx, ny, nz = px * inv, py * inv, pz * inv
        r = geo[3]
        return (geo[0] + nx * r, geo[1] + ny * r, geo[2] + nz * r), (nx, ny, nz)
    p = (
        geo[0] + u * geo[3] + v * geo[6],
        geo[1] + u * geo[4] + v * geo[7],
        geo[2] + u * geo[5] + v * geo[8],
    )
    nx = geo[4] * geo[8] - geo[5] * geo[7]
    ny = geo[5] * geo[6] - geo[3] * geo[8]
    nz = geo[3] * geo[7] - geo[4] * geo[6]
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return p, (nx * inv, ny * inv, nz * inv)


# Relative size of the offset that lifts a ray's origin off the surface it leaves. Hit points are
# exact to ~1e-15 of the primitive's coordinates (see surface_point); 1e-9 of them is a million
# times that and still far below anything visible, at any scene scale (tests/…/test_scale.py).
SPAWN_EPSILON = 1e-9


@kernel
def spawn_offset(p, n, w, prim_scale):
    """Origin for a ray leaving ``p`` in direction ``w``, pushed to the side of the normal that w
    lies on."""
    eps = SPAWN_EPSILON * max(prim_scale, max(abs(p[0]), abs(p[1]), abs(p[2])))
    if w[0] * n[0] + w[1] * n[1] + w[2] * n[2] < 0.0:
        eps = -eps
    return (p[0] + eps * n[0], p[1] + eps * n[1], p[2] + eps * n[2])


# Candidates near a sphere beyond which ``spheres_alone`` gives up on it (counts it not alone)
ALONE_MAX_NEAR = 4096


def _enters_ball(kind: int, geo: np.ndarray, c: np.ndarray, r: float) -> bool:
    """Whether the surface of primitive (kind, geo) has a point closer than r to c."""
    if kind == SPHERE:
        return abs(float(np.linalg.norm(c - geo[0:3])) - geo[3]) < r
    p0, e1, e2 = geo[0:3], geo[3:6], geo[6:9]
    # The closest point of a planar region is the projection of c, when that lies inside it,
    # or a point of its boundary
    g11, g12, g22 = float(e1 @ e1), float(e1 @ e2), float(e2 @ e2)
    det = g11 * g22 - g12 * g12
    if det > 0.0:  # (a degenerate one has only its edges)
        f1, f2 = float(e1 @ (c - p0)), float(e2 @ (c - p0))
        a, b = (g22 * f1 - g12 * f2) / det, (g11 * f2 - g12 * f1) / det
        inside = a >= 0.0 and b >= 0.0 and (a + b <= 1.0 if kind == TRIANGLE
                                            else a <= 1.0 and b <= 1.0)
        if inside and float(np.linalg.norm(c - (p0 + a * e1 + b * e2))) < r:
            return True
    corners = [p0, p0 + e1, p0 + e2] if kind == TRIANGLE else [p0, p0 + e1, p0 + e1 + e2, p0 + e2]
    for s0, s1 in zip(corners, corners[1:] + corners[:1], strict=True):
        e = s1 - s0
        w = min(max(float((c - s0) @ e) / float(e @ e), 0.0), 1.0) if e @ e > 0.0 else 0.0
        if float(np.linalg.norm(c - (s0 + w * e))) < r:
            return True
    return False


def spheres_alone(kind: np.ndarray, geo: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  which: np.ndarray) -> np.ndarray:
    """Per primitive, 1 for a sphere among ``which`` (a mask) that no other primitive's surface
    enters: from a point inside it, the closest surface along any ray is its own (what a walk in
    its medium asks at every step, ``trace_path``). Surfaces that only touch it (a sphere resting
    on a floor), or reach into it by less than ``SPAWN_EPSILON`` of its scale (the scale of a
    ray's offset from a surface), leave it alone. A sphere with more than ``ALONE_MAX_NEAR``
    primitives near it (bounds overlapping its own) is not examined, and counts as not alone."""
    alone = np.zeros(len(kind), np.int8)
    for k in np.flatnonzero(which & (kind == SPHERE)):
        c, r = geo[k, 0:3], float(geo[k, 3])
        near = np.flatnonzero(np.all(lo < c + r, axis=1) & np.all(hi > c - r, axis=1))
        near = near[near != k]
        if len(near) > ALONE_MAX_NEAR:
            continue
        inner = r - SPAWN_EPSILON * max(r, float(np.abs(c).max()))
        alone[k] = not any(_enters_ball(int(kind[j]), geo[j], c, inner) for j in near)
    return alone


@alloc_kernel
def prim_bounds(kind, geo):
    """Axis-aligned bounds (lo, hi), each (n, 3), of every primitive.

    A kernel rather than vectorized NumPy: the masked NumPy version made ~10 temporary (n, 3)
    arrays, which for a million-triangle mesh were the peak of the scene compile's memory.
    """
    n = kind.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for i in range(n):
        for a in range(3):
            if kind[i] == SPHERE:
                lo[i, a] = geo[i, a] - geo[i, 3]
                hi[i, a] = geo[i, a] + geo[i, 3]
                continue
            p0 = geo[i, a]
            p1 = p0 + geo[i, 3 + a]
            p2 = p0 + geo[i, 6 + a]
            lo[i, a] = min(min(p0, p1), p2)
            hi[i, a] = max(max(p0, p1), p2)
            if kind[i] == QUAD:
                p3 = p1 + geo[i, 6 + a]
                lo[i, a] = min(lo[i, a], p3)
                hi[i, a] = max(hi[i, a], p3)
    return lo, hi


@kernel
def interpolated_normal(prim_normal, kind, prim, u, v, n):
    """The shading normal of a triangle hit at barycentrics (u, v): its corners' normals
    (``prim_normal``, world space, unit) interpolated and normalized, turned to the side of the
    outward geometric normal n; n itself where the primitive has none (a NaN first component
    marks a triangle of a mesh without normals) or the interpolation vanishes."""
    if kind != TRIANGLE or prim_normal.shape[0] == 0:
        return n
    r = prim_normal[prim]
    if not r[0] == r[0]:
        return n
    w = 1.0 - u - v
    x = w * r[0] + u * r[3] + v * r[6]
    y = w * r[1] + u * r[4] + v * r[7]
    z = w * r[2] + u * r[5] + v * r[8]
    length = math.sqrt(x * x + y * y + z * z)
    if not length > 1e-12:
        return n
    x, y, z = x / length, y / length, z / length
    if x * n[0] + y * n[1] + z * n[2] < 0.0:
        return (-x, -y, -z)
    return (x, y, z)
