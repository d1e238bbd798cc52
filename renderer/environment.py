"""Light from an environment image (scene format v1.1, "Light from an environment").

A latitude–longitude image of linear radiance, seen by every ray that escapes and sampled as a
light. For a direction d in the environment's own frame (the world direction rotated by the
inverse of ``rotate``):

    u = atan2(d.x, −d.z)/(2π) mod 1   (grows to the right of the image; +X at u = 0.25, −Z at 0)
    v = acos(d.y)/π                   (0 at the top row, +Y; 1 at the bottom row, −Y)

Radiance is bilinear between texels as Mitsuba 3's ``envmap`` places them (checked against it:
``tests/renderer/test_environment.py``): column i's centre at u = (i + ½)/W, wrapping at the seam,
and row j at v = j/(H − 1), the first row at the top pole and the last at the bottom one.

Sampling (pbrt-v4's ImageInfiniteLight, Mitsuba's envmap): a piecewise-constant 2D distribution
over the cells of that bilinear lookup, (H − 1) rows × W columns, each split k × k (k = 4 up to
1024 × 1024 texels, 2 up to 2048 × 2048, else 1: ``subdivision``), each part weighted by the
exact mean of the bilinear luminance over it (so a part is never 0 where the radiance is not)
times sin θ at its centre; a
row from the marginal CDF, a column from the row's conditional CDF, a point uniformly inside the
part. The density in (u, v) is constant per part, p(u, v) = P(part)·k²·W·(H − 1), and per unit
solid angle p(ω) = p(u, v)/(2π² sin θ), with sin θ of the direction itself. ``environment_pdf``
reads the same CDFs, so lookup and sampler agree exactly. The split follows the bilinear radiance
of a sun a texel or two wide more closely than one constant a cell (Mitsuba samples a bilinear
density instead): on ``tests/data/env_diffuse_sphere.json`` at 64 spp the MSE against Mitsuba's
16384-spp reference was 1.77× Mitsuba's own at k = 1, 1.22× at k = 2 and 1.04× at k = 4; on
``env_rough_glass_sphere.json`` 1.32×, 1.25×, 1.13× (four seeds each).

Arrays (``SceneArrays``): ``env_image`` (H, W, 3) float32, radiance × ``scale``;
``env_marginal`` (1, k(H − 1) + 1) the rows' CDF (0 first, 1 last); ``env_conditional``
(k(H − 1), kW + 1) each row's CDF; ``env_rotation`` (3, 3), local → world. A scene without an
environment carries placeholders of the same types (``no_environment``).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.jit import inline_kernel, kernel
from renderer.vecmath import LUMINANCE

INV_2PI2 = 1.0 / (2.0 * math.pi * math.pi)


# --- Host: the arrays ---------------------------------------------------------------------------


MAX_CELLS = 1 << 24
"""The most cells a subdivision may make (128 MiB of float64 CDF); an image larger than that is
sampled by its cells unsplit (an 8192 × 4096 image: 2²⁵ cells, 256 MiB)."""


def subdivision(height: int, width: int) -> int:
    """Parts of the distribution per lookup cell along each axis: the largest of 4, 2, 1 that
    keeps the distribution within ``MAX_CELLS`` (4 up to 1024 × 1024 texels, 2 up to 2048 ×
    2048)."""
    for k in (4, 2):
        if k * k * (height - 1) * width <= MAX_CELLS:
            return k
    return 1


def cell_weights(image: np.ndarray, k: int = 1) -> np.ndarray:
    """(k(H − 1), kW) sampling weights: each bilinear cell split k × k, each part weighted by
    the mean of the bilinear luminance over it (corners weighted by (1 − a)(1 − b), a(1 − b), …
    at the part's centre (a, b)) times sin θ at its centre. A part is > 0 wherever the radiance
    in it is."""
    lum = np.asarray(image, np.float64) @ LUMINANCE  # (H, W)
    h, w = lum.shape
    right = np.roll(lum, -1, axis=1)  # the column after each, wrapping at the seam
    f00, f10, f01, f11 = lum[:-1], right[:-1], lum[1:], right[1:]
    out = np.empty((k * (h - 1), k * w))
    for b in range(k):  # rows within a cell
        wy = (b + 0.5) / k
        for a in range(k):  # columns within a cell
            wx = (a + 0.5) / k
            out[b::k, a::k] = ((1 - wy) * ((1 - wx) * f00 + wx * f10)
                               + wy * ((1 - wx) * f01 + wx * f11))
    sin_theta = np.sin(math.pi * (np.arange(k * (h - 1)) + 0.5) / (k * (h - 1)))
    return out * sin_theta[:, None]


def build_environment(image: np.ndarray, scale: float, rotation: np.ndarray):
    """(env_image, env_marginal, env_conditional, env_rotation, power_per_area): the arrays of
    an environment, and ∫L dω's luminance (the light's power is π r² times it, r the scene's
    bounding radius: pbrt-v4's ImageInfiniteLight::Phi)."""
    image = np.ascontiguousarray(np.asarray(image, np.float32) * np.float32(scale))
    h, w, _ = image.shape
    k = subdivision(h, w)
    f = cell_weights(image, k)
    rows, cols = f.shape
    row_sum = f.sum(axis=1)
    total = float(row_sum.sum())
    conditional = np.zeros((rows, cols + 1))
    conditional[:, 1:] = np.cumsum(f, axis=1)
    nonzero = row_sum > 0.0
    conditional[nonzero] /= row_sum[nonzero, None]
    # A black row is never chosen; its CDF is left uniform so that it stays well-formed
    conditional[~nonzero] = np.linspace(0.0, 1.0, cols + 1)
    conditional[:, -1] = 1.0
    marginal = np.zeros((1, rows + 1))
    marginal[0, 1:] = np.cumsum(row_sum)
    if total > 0.0:
        marginal /= total
    marginal[0, -1] = 1.0
    integral = total * 2.0 * math.pi * math.pi / (rows * cols)  # ≈ ∫ luminance dω
    return (image, marginal, conditional, np.ascontiguousarray(rotation, np.float64), integral)


def no_environment():
    """Placeholders of the environment's arrays for a scene without one (same types, so the
    kernels compile once for both)."""
    return (np.zeros((2, 1, 3), np.float32), np.array([[0.0, 1.0]]), np.array([[0.0, 1.0]]),
            np.eye(3))


# --- Kernels ------------------------------------------------------------------------------------


@kernel
def _find_interval(cdf, row, u):
    """The last i < cdf.shape[1] − 1 with cdf[row, i] ≤ u: the bin of a CDF that u falls in
    (zero-width bins are skipped, since the last of equal values is taken)."""
    lo = 0
    hi = cdf.shape[1] - 2
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[row, mid] <= u:
            lo = mid
        else:
            hi = mid - 1
    return lo


@kernel
def direction_to_uv(rot, d):
    """(u, v, sin θ) of the world direction d in the environment's frame (rotated by rot⁻¹)."""
    x = rot[0, 0] * d[0] + rot[1, 0] * d[1] + rot[2, 0] * d[2]
    y = rot[0, 1] * d[0] + rot[1, 1] * d[1] + rot[2, 1] * d[2]
    z = rot[0, 2] * d[0] + rot[1, 2] * d[1] + rot[2, 2] * d[2]
    u = math.atan2(x, -z) * (0.5 / math.pi)
    if u < 0.0:
        u += 1.0
    if u >= 1.0:
        u = 0.0
    v = math.acos(min(1.0, max(-1.0, y))) / math.pi
    return u, v, math.sqrt(x * x + z * z)


@kernel
def environment_radiance(image, u, v):
    """Bilinear radiance at (u, v) (column centres at (i + ½)/W, wrapping; rows from pole to
    pole)."""
    h = image.shape[0]
    w = image.shape[1]
    x = u * w - 0.5
    x0 = math.floor(x)
    fx = x - x0
    c0 = int(x0) % w
    c1 = (c0 + 1) % w
    y = v * (h - 1)
    r0 = min(int(y), h - 2)
    fy = y - r0
    r1 = r0 + 1
    out0 = ((1.0 - fy) * ((1.0 - fx) * image[r0, c0, 0] + fx * image[r0, c1, 0])
            + fy * ((1.0 - fx) * image[r1, c0, 0] + fx * image[r1, c1, 0]))
    out1 = ((1.0 - fy) * ((1.0 - fx) * image[r0, c0, 1] + fx * image[r0, c1, 1])
            + fy * ((1.0 - fx) * image[r1, c0, 1] + fx * image[r1, c1, 1]))
    out2 = ((1.0 - fy) * ((1.0 - fx) * image[r0, c0, 2] + fx * image[r0, c1, 2])
            + fy * ((1.0 - fx) * image[r1, c0, 2] + fx * image[r1, c1, 2]))
    return out0, out1, out2


@kernel
def _uv_pdf(image, marginal, conditional, u, v):
    """Density in (u, v) of the cell that holds (u, v)."""
    rows = conditional.shape[0]
    cols = conditional.shape[1] - 1
    x = u * cols - 0.5 * (cols // image.shape[1])  # the k cells a texel: half a texel is k/2
    if x < 0.0:
        x += cols
    c = min(int(x), cols - 1)
    r = min(int(v * rows), rows - 1)
    p_row = marginal[0, r + 1] - marginal[0, r]
    p_col = conditional[r, c + 1] - conditional[r, c]
    return p_row * p_col * cols * rows


@kernel
def environment_pdf(image, marginal, conditional, rot, d):
    """Solid-angle density with which ``environment_sample`` picks the world direction d."""
    u, v, sin_theta = direction_to_uv(rot, d)
    if sin_theta <= 0.0:
        return 0.0
    return _uv_pdf(image, marginal, conditional, u, v) * INV_2PI2 / sin_theta


@inline_kernel
def environment_sample(image, marginal, conditional, rot, u1, u2):
    """A world direction from the environment's distribution: (wi, radiance, solid-angle pdf);
    pdf = 0 when nothing can be sampled (a black image, a direction at a pole)."""
    rows = conditional.shape[0]
    cols = conditional.shape[1] - 1
    # A row from the marginal, a column from its conditional, a point inside the cell
    r = _find_interval(marginal, 0, u1)
    p_row = marginal[0, r + 1] - marginal[0, r]
    if not p_row > 0.0:
        return (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0
    dy = min((u1 - marginal[0, r]) / p_row, 1.0)
    c = _find_interval(conditional, r, u2)
    p_col = conditional[r, c + 1] - conditional[r, c]
    if not p_col > 0.0:
        return (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0
    dx = min((u2 - conditional[r, c]) / p_col, 1.0)
    u = (c + dx + 0.5 * (cols // image.shape[1])) / cols
    if u >= 1.0:
        u -= 1.0
    v = (r + dy) / rows
    theta = math.pi * v
    phi = 2.0 * math.pi * u
    sin_theta = math.sin(theta)
    if sin_theta <= 0.0:
        return (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0
    lx, ly, lz = math.sin(phi) * sin_theta, math.cos(theta), -math.cos(phi) * sin_theta
    wi = (rot[0, 0] * lx + rot[0, 1] * ly + rot[0, 2] * lz,
          rot[1, 0] * lx + rot[1, 1] * ly + rot[1, 2] * lz,
          rot[2, 0] * lx + rot[2, 1] * ly + rot[2, 2] * lz)
    pdf = p_row * p_col * cols * rows * INV_2PI2 / sin_theta
    return wi, environment_radiance(image, u, v), pdf
