"""Light sampling for next-event estimation, and the densities multiple importance sampling needs.

Every light is a row of the light table: ``light_kind``, ``light_prim`` (the primitive of an area
light) and ``light_data`` (position or direction in 0:3, intensity / irradiance / radiance in 3:6).
One light is chosen per shading point with probability ``light_pmf`` in proportion to its power
(pbrt-v4's PowerLightSampler), then a point or direction on it.

- area lights (emissive quads, triangles, spheres) emit on the side their normal faces: quads on
  cross(edge1, edge2), spheres, boxes and meshes outward. Quads and triangles are sampled uniformly
  by area, spheres uniformly inside the cone they subtend (pbrt-v4 Sphere::Sample);
- point lights: intensity I (W/sr), radiance at distance r is I/r²;
- directional lights: irradiance E (W/m²) on a surface facing them;
- the constant background: radiance L in every direction, sampled uniformly over the sphere;
- the environment image (``renderer.environment``): its radiance by direction, sampled by
  luminance × sin θ from a piecewise-constant 2D distribution.
"""

from __future__ import annotations

import math

from renderer.environment import environment_sample
from renderer.geometry.shapes import QUAD, SPHERE
from renderer.jit import inline_kernel, kernel
from renderer.sampling import INV_4PI, sample_discrete, uniform_cone, uniform_triangle
from renderer.vecmath import to_world

AREA = 0
POINT = 1
DIRECTIONAL = 2
BACKGROUND = 3
ENVIRONMENT = 4

INF = math.inf


@kernel
def _sphere_cone(geo, p):
    """(1 − cos θmax, unit axis, distance to centre) of the cone a sphere subtends from p; omc < 0
    when p is inside or on the sphere."""
    ax, ay, az = geo[0] - p[0], geo[1] - p[1], geo[2] - p[2]
    d2 = ax * ax + ay * ay + az * az
    r = geo[3]
    if d2 <= r * r:
        return -1.0, (0.0, 0.0, 1.0), 0.0
    dist = math.sqrt(d2)
    sin2 = r * r / d2
    # 1 − cos θmax = sin²/(1 + cos), exact even when the cone is tiny
    omc = sin2 / (1.0 + math.sqrt(1.0 - sin2))
    return omc, (ax / dist, ay / dist, az / dist), dist


@inline_kernel
def sample_light(light_kind, light_prim, light_data, light_cdf, light_pmf, prim_kind, prim_geo,
                 env_image, env_marginal, env_conditional, env_rotation, p, u_sel, u1, u2):
    """Choose a light and a direction to it from p (``env_*``: the environment's arrays).

    Returns (wi, Li, pdf, t_max, is_delta): Li is the radiance (or, for delta lights, the
    irradiance-like quantity I/r² or E) arriving along wi, pdf the probability density per unit
    solid angle including the light choice (for delta lights, just the choice probability), t_max
    the distance the shadow ray must be clear for. pdf = 0 means no contribution.
    """
    zero = (0.0, 0.0, 0.0)
    n_lights = light_kind.shape[0]
    if n_lights == 0:
        return zero, zero, 0.0, 0.0, False
    li = sample_discrete(light_cdf, u_sel)  # the light whose cdf bracket contains u_sel
    pmf = light_pmf[li]
    kind = light_kind[li]
    radiance = (light_data[li, 3], light_data[li, 4], light_data[li, 5])
    if kind == POINT:
        dx = light_data[li, 0] - p[0]
        dy = light_data[li, 1] - p[1]
        dz = light_data[li, 2] - p[2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 == 0.0:
            return zero, zero, 0.0, 0.0, True
        dist = math.sqrt(d2)
        wi = (dx / dist, dy / dist, dz / dist)
        return wi, (radiance[0] / d2, radiance[1] / d2, radiance[2] / d2), pmf, dist, True
    if kind == DIRECTIONAL:
        wi = (-light_data[li, 0], -light_data[li, 1], -light_data[li, 2])
        return wi, radiance, pmf, INF, True
    if kind == BACKGROUND:
        z = 1.0 - 2.0 * u1
        r = math.sqrt(max(0.0, 1.0 - z * z))
        phi = 2.0 * math.pi * u2
        wi = (r * math.cos(phi), r * math.sin(phi), z)
        return wi, radiance, pmf * INV_4PI, INF, False
    if kind == ENVIRONMENT:
        wi, le, pdf = environment_sample(env_image, env_marginal, env_conditional, env_rotation,
                                         u1, u2)
        return wi, le, pmf * pdf, INF, False

    # Area light
    prim = light_prim[li]
    geo = prim_geo[prim]
    if prim_kind[prim] == SPHERE:
        omc, axis, dist_c = _sphere_cone(geo, p)
        if omc <= 0.0:
            # Inside an emitting sphere: it emits outward only, so nothing arrives.
            return zero, zero, 0.0, 0.0, False
        wi = to_world(uniform_cone(u1, u2, omc), axis)
        # Distance to the near intersection along wi (clamped to the tangent point when rounding
        # puts wi a hair outside the sphere)
        b = (geo[0] - p[0]) * wi[0] + (geo[1] - p[1]) * wi[1] + (geo[2] - p[2]) * wi[2]
        cx = geo[0] - p[0] - b * wi[0]
        cy = geo[1] - p[1] - b * wi[1]
        cz = geo[2] - p[2] - b * wi[2]
        h2 = geo[3] * geo[3] - (cx * cx + cy * cy + cz * cz)
        t = b - math.sqrt(max(0.0, h2))
        pdf = pmf / (2.0 * math.pi * omc)
        return wi, radiance, pdf, t, False

    # Quad or triangle, uniform by area
    if prim_kind[prim] == QUAD:
        s, t = u1, u2
    else:
        s, t = uniform_triangle(u1, u2)
    qx = geo[0] + s * geo[3] + t * geo[6]
    qy = geo[1] + s * geo[4] + t * geo[7]
    qz = geo[2] + s * geo[5] + t * geo[8]
    nx = geo[4] * geo[8] - geo[5] * geo[7]
    ny = geo[5] * geo[6] - geo[3] * geo[8]
    nz = geo[3] * geo[7] - geo[4] * geo[6]
    n_len = math.sqrt(nx * nx + ny * ny + nz * nz)
    area = n_len if prim_kind[prim] == QUAD else 0.5 * n_len
    dx, dy, dz = qx - p[0], qy - p[1], qz - p[2]
    d2 = dx * dx + dy * dy + dz * dz
    if d2 == 0.0:
        return zero, zero, 0.0, 0.0, False
    dist = math.sqrt(d2)
    wi = (dx / dist, dy / dist, dz / dist)
    cos_l = -(wi[0] * nx + wi[1] * ny + wi[2] * nz) / n_len
    if cos_l <= 0.0:
        return zero, zero, 0.0, 0.0, False  # the light's back: it emits on its normal side only
    pdf = pmf * d2 / (cos_l * area)
    return wi, radiance, pdf, dist, False


@kernel
def area_light_pdf(light_pmf, li, kind, geo, p, q, nq):
    """Solid-angle density with which ``sample_light`` picks the point q (normal nq) from p."""
    pmf = light_pmf[li]
    if kind == SPHERE:
        omc, _, _ = _sphere_cone(geo, p)
        if omc <= 0.0:
            return 0.0
        return pmf / (2.0 * math.pi * omc)
    nx = geo[4] * geo[8] - geo[5] * geo[7]
    ny = geo[5] * geo[6] - geo[3] * geo[8]
    nz = geo[3] * geo[7] - geo[4] * geo[6]
    n_len = math.sqrt(nx * nx + ny * ny + nz * nz)
    area = n_len if kind == QUAD else 0.5 * n_len
    dx, dy, dz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    d2 = dx * dx + dy * dy + dz * dz
    cos_l = abs(dx * nq[0] + dy * nq[1] + dz * nq[2]) / math.sqrt(d2)
    if cos_l == 0.0:
        return 0.0
    return pmf * d2 / (cos_l * area)
