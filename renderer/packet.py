"""The packet kernel: 16 paths at once, one in each float32 lane of the CPU's vectors.

The scalar kernel (``renderer.integrators.path``) traces one path at a time in float64 and
vectorizes only its loop over a flat scene's primitives. Mitsuba 3's ``llvm_ad_rgb`` gets its lead
on the CPU from running 8–16 paths in the vector lanes in float32 (docs/performance.md). This
kernel does the same for the scenes it covers: each thread keeps a packet of ``LANES`` paths,
their state by column in one float32 array, and runs every stage as a loop over the lanes that
LLVM vectorizes (selects instead of branches; a stage per function, so that no value of one
stage's loop is live after it):

- closest hit: every primitive against the 16 rays (the flat scene's loop turned inside out);
- gather: each lane's hit primitive's normal, albedo and emission (indexed loads: LLVM leaves
  this loop scalar, as it cannot bound the loads' addresses), and where the scene has several
  lights one picked by power (a scalar loop over the cumulative table);
- shade: emission seen (weighted by Veach's power heuristic against light sampling), a point on
  the light and its shadow ray, the cosine-weighted next direction, Russian roulette (Lucent's
  rule: from the ``RR_DEPTH``-th scattering event, q = min(max β, ``RR_MAX``));
- shadow: every primitive against the 16 shadow rays;
- a lane whose path ended writes its sample to the tile's buffer and starts the next path of
  its thread's pixels at once (path regeneration: the lanes stay full).

The seed paper's ``single_scatter`` media (Lundgren, "A Simple Approach To Translucent
Materials") add stages, run only in a scene that has them: inside a medium a free flight that
may end at its one scattering event, or after that event the segment's attenuation
(``_flight``); the medium entered or left where the ray crossed a surface straight on
(``_enter``); the event's light sample, weighted against the Henyey–Greenstein phase function,
and its direction (``_scatter``); shadow rays through the media, which sum their optical depth as
``renderer.integrators.shadow.flat_transmittance`` does (``_shadow_media``). exp and log are
polynomials (``exp32``, ``log32``), as libm's calls would keep LLVM from vectorizing the loops.

Covered (``unsupported`` says why not): flat scenes (at most ``FLAT_MAX`` primitives) of quads
and triangles, untextured ``diffuse`` and grey ``single_scatter`` materials, emitting quads and
triangles as the only lights, no background, the independent and the sobol samplers (a medium's
free flights draw independently). Anything else renders with the scalar kernel.

Randomness: each path starts from its sample's key (``renderer.rng.sample_key`` of the seed, the
pixel and the global sample index), so a tile's image does not depend on how the frame was cut or
which thread took it; within a path each draw hashes a 32-bit counter that starts from that key
(a Weyl sequence through Wellons' lowbias32; the top 24 bits a float32 draw). The image is
deterministic but not the scalar kernel's: it is checked against Mitsuba 3's
(tests/renderer/test_packet.py), as the scalar kernel is. Under the sobol sampler the camera
jitter and the first ``SOBOL_VERTICES`` vertices' light pick, point on the light and direction
come from the scalar kernel's sequences (``renderer.integrators.sampler.draw``: the same pixel
seeds, blocks and shuffled, Owen-scrambled (0,2)-sequences), computed in 32-bit lanes
(``_sobol_stage``) to 24 bits; the roulette and deeper vertices stay independent.

Float32, and where it is not enough: ray origins are moved off a surface by ``EPS_REL`` of the
scene's scale (the largest coordinate of any primitive or of the camera), and hits nearer than
that are ignored. float32 puts a point within ~6e-8 of that scale, 1600 times less than the
offset, so no ray finds the surface it leaves; detail finer than 1e-4 of the scene's scale (a
gap, a thin slab) is lost, which the scalar kernel's float64 keeps. A scene more than ``FAR``
times its size from the origin is the scalar kernel's. The film sums are float64, as the scalar
kernel's.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from renderer.film.buffer import SampleBuffer
from renderer.film.samples import add_sample
from renderer.geometry.flat import FLAT_MAX
from renderer.geometry.shapes import QUAD, TRIANGLE, prim_bounds
from renderer.integrators.path import camera_ray
from renderer.integrators.roulette import RR_DEPTH, RR_MAX
from renderer.integrators.sampler import PIXEL_SEED_SALT, SOBOL_BLOCKS, SOBOL_VERTICES
from renderer.jit import JIT_OPTIONS, claim_row, kernel, run_chunks
from renderer.lights import AREA
from renderer.materials.bsdf import DIFFUSE, SINGLE_SCATTER
from renderer.materials.diffuse import ALBEDO
from renderer.materials.phase import ISOTROPIC_G
from renderer.materials.translucent import ALBEDO as MEDIUM_ALBEDO
from renderer.materials.translucent import CHROMATIC, DENSITY, SURFACE_FRACTION, G
from renderer.rng import (
    key_of_sample,
    mix64,
    pixel_key,
    sobol_block_seeds,
    sobol_value,
)

LANES = 16
F32 = np.float32
EPS_REL = 1e-4  # the ray offset and least hit distance, as a share of the scene's scale
# A scene (camera included) whose largest coordinate is more than this many times its size is
# left to the scalar kernel: the offset, EPS_REL of the coordinate, would grow past 1e-3 of the
# scene (tests/renderer/test_packet.py renders the Cornell box moved away from the origin)
FAR = 10.0
_INF = np.float32(1e30)
_INV_PI = np.float32(1.0 / math.pi)
_INV_4PI = np.float32(0.25 / math.pi)
# The least cosine at a light in an MIS weight: its square times a density stays a normal float32
# (denormals cost Intel's cores a microcode assist each: the shading stage ran 1.5x slower)
_COS_MIN = np.float32(1e-10)
_QUARTER_PI = np.float32(math.pi / 4.0)
_RR_MAX = np.float32(RR_MAX)
_RR_DEPTH = np.int32(RR_DEPTH)
_WEYL = np.uint32(0x9E3779B9)
_H1 = np.uint32(0x7FEB352D)
_H2 = np.uint32(0x846CA68B)
_TWO_POW_M24 = np.float32(1.0 / 16777216.0)

# The helpers of the lane loops are inlined by numba before LLVM sees the loops: a call LLVM
# inlines later (``inline_kernel``'s ``alwaysinline``) is still a call, returning a tuple, when
# its loop vectorizer runs, and the shading loop then stayed scalar (3.8-4.0 against 4.6-6.0 M
# paths/s on the Cornell box)
_inlined = numba.njit(inline="always", _nrt=False, **JIT_OPTIONS)

# The packet's state: row k of the float32 array (P) holds lanes [16k, 16k + 16)
(OX, OY, OZ, DX, DY, DZ, TR, TG, TB, LR, LG, LB, PDF_B, T_HIT, SX, SY, SZ, S_DIST, CR, CG, CB,
 NX, NY, NZ, AR, AG, AB, ER, EG, EB, E_PA,
 QOX, QOY, QOZ, QAX, QAY, QAZ, QBX, QBY, QBZ, QNX, QNY, QNZ, QER, QEG, QEB, Q_PA, Q_TRI,
 U_PICK, U_L1, U_L2, U_B1, U_B2,
 PPX, PPY, PPZ, HSS, HSF, MSIG, MAR, MAG, MAB, MG, FLIGHT, TAU, OPEN, STR) = (
    k * LANES for k in range(67))
FLOAT_ROWS = 67
# PPX…: the path's last scattering vertex (the light pdf of an emitter found next is measured
# from it); HSS, HSF: 1 where the hit primitive is single_scatter, its surface fraction; MSIG…:
# the medium the lane's ray is in (its grey σt, albedo, g); FLIGHT: the free flight's length;
# TAU, OPEN, STR: the shadow ray's optical depth, the σt of the media open along it, and the
# surfaces' share let in
# The int32 array (Q); SIDX is the path's global sample index (the sobol sampler's); IN_MED: the
# ray is inside a single_scatter medium, DONE: which has had its one event; EVENT: this segment
# ended at that event; N_OPEN: media open along the shadow ray; CROSS: 1 (−1) where the ray
# crossed into (out of) a single_scatter medium at this segment's surface
HIT, DEPTH, OCCLUDED, DEAD, SEGMENTS, LIGHT, SIDX, IN_MED, DONE, EVENT, N_OPEN, CROSS = (
    k * LANES for k in range(12))
INT_ROWS = 12
# The sobol sampler's seeds of each lane's pixel (uint32, row 3b + c: block b's index shuffle (c
# 0) and point scrambles (c 1, 2), ``sobol_block_seeds``); a vertex's blocks are those of
# ``renderer.integrators.sampler.draw``: 1 + 5v the light pick, + 1 the point on the light, + 3
# the direction
SEED_ROWS = 3 * SOBOL_BLOCKS
if SOBOL_VERTICES != 2:  # _lane_seed selects between vertex 0's and vertex 1's seeds
    raise ImportError("renderer.packet's sobol stage is written for SOBOL_VERTICES = 2")
# Primitive columns (float32, (PRIM_ROWS, primitives)): corner, edges, unit normal (edge1 ×
# edge2), albedo, emission, the emission's light pmf over its area (0 for a surface that does not
# emit), 1 for a triangle; then its material's medium: 1 for single_scatter, the surface
# fraction, σt (grey: the kernel covers no chromatic medium), g
PRIM_ROWS = 24
SINGLE, FRACTION, SIGMA, PHASE_G = 20, 21, 22, 23  # the medium's rows of the columns


def unsupported(scene) -> str | None:
    """Why the packet kernel cannot render this ``CompiledScene``, or None when it can."""
    S = scene.arrays
    n = len(S.prim_kind)
    if n == 0:
        return "no primitives"
    if n > FLAT_MAX:
        return f"{n} primitives (the packet kernel tests every one: at most {FLAT_MAX})"
    if not np.isin(S.prim_kind, (QUAD, TRIANGLE)).all():
        return "spheres (the packet kernel intersects quads and triangles)"
    mats = np.unique(S.prim_material)
    if not np.isin(S.mat_kind[mats], (DIFFUSE, SINGLE_SCATTER)).all():
        return "materials other than diffuse and single_scatter"
    single = mats[S.mat_kind[mats] == SINGLE_SCATTER]
    if (S.mat_param[single, CHROMATIC] > 0.0).any():
        return "a chromatic single_scatter medium (σt per channel)"
    if (S.prim_light[np.isin(S.prim_material, single)] >= 0).any():
        return "an emitting single_scatter surface"
    if (S.mat_tex[mats, 1] >= 0.0).any():
        return "textured materials"
    if S.prim_normal.shape[0] > 0:
        return "shading normals"
    if (S.light_kind != AREA).any() or S.env_light[0] >= 0 or S.background.max() > 0.0:
        return "lights other than emitting surfaces (point, directional, the background)"
    if len(S.light_kind) == 0:
        return "no light"
    lo, hi = prim_bounds(S.prim_kind, S.prim_geo)
    size = float(np.linalg.norm(hi.max(axis=0) - lo.min(axis=0)))
    if scene_scale(scene) > FAR * size:
        return (f"a scene {scene_scale(scene):.3g} from the origin for a size of {size:.3g} "
                "(float32 lanes: the scalar kernel keeps float64)")
    return None


def scene_scale(scene) -> float:
    """The largest coordinate of any primitive or the camera: what float32's rounding of a point
    is relative to."""
    S = scene.arrays
    return max(float(S.prim_scale.max()), float(np.abs(S.camera[0:3]).max()))


def prim_columns(scene) -> np.ndarray:
    """The scene's primitives by column (``PRIM_ROWS`` rows of float32)."""
    S = scene.arrays
    geo = S.prim_geo
    n = len(S.prim_kind)
    cols = np.zeros((PRIM_ROWS, n))
    cols[0:9] = geo[:, 0:9].T
    normal = np.cross(geo[:, 3:6], geo[:, 6:9])
    length = np.linalg.norm(normal, axis=1)
    cols[9:12] = (normal / np.where(length > 0.0, length, 1.0)[:, None]).T
    single = S.mat_kind[S.prim_material] == SINGLE_SCATTER
    mp = S.mat_param[S.prim_material]
    cols[12:15] = np.where(single, mp[:, MEDIUM_ALBEDO:MEDIUM_ALBEDO + 3].T,
                           mp[:, ALBEDO:ALBEDO + 3].T)
    cols[SINGLE] = single
    cols[FRACTION] = np.where(single, mp[:, SURFACE_FRACTION], 0.0)
    cols[SIGMA] = np.where(single, mp[:, DENSITY], 0.0)
    cols[PHASE_G] = np.where(single & (np.abs(mp[:, G]) >= ISOTROPIC_G), mp[:, G], 0.0)
    tri = S.prim_kind == TRIANGLE
    area = np.where(tri, 0.5 * length, length)
    lit = S.prim_light >= 0
    cols[15:18, lit] = S.light_data[S.prim_light[lit], 3:6].T
    cols[18, lit] = S.light_pmf[S.prim_light[lit]] / area[lit]
    cols[19] = tri
    return np.ascontiguousarray(cols, F32)


@_inlined
def _step(z):
    """The lane's next counter (a Weyl sequence in 32 bits)."""
    return np.uint32(z + _WEYL)


@_inlined
def _float(z):
    """A uniform float32 in [0, 1) from a counter: the top 24 bits of Wellons' lowbias32 hash.
    32-bit integer lanes throughout (numba widens narrower integers to 64 bits; the casts let
    LLVM keep 32, twice the lanes of a 64-bit generator)."""
    z = np.uint32(z ^ (z >> np.uint32(16)))
    z = np.uint32(z * _H1)
    z = np.uint32(z ^ (z >> np.uint32(15)))
    z = np.uint32(z * _H2)
    z = np.uint32(z ^ (z >> np.uint32(16)))
    return np.float32(z >> np.uint32(8)) * _TWO_POW_M24


@_inlined
def sin_cos_quarter(x):
    """(sin x, cos x) for |x| ≤ π/4 by their Taylor polynomials to x⁹ and x⁸ (errors below
    3e-8 and 4e-7 there, under float32's own rounding): LLVM vectorizes them, not libm's calls."""
    x2 = x * x
    s = x * (F32(1.0) + x2 * (F32(-1.0 / 6.0) + x2 * (F32(1.0 / 120.0) + x2 * (
        F32(-1.0 / 5040.0) + x2 * F32(1.0 / 362880.0)))))
    c = F32(1.0) + x2 * (F32(-0.5) + x2 * (F32(1.0 / 24.0) + x2 * (
        F32(-1.0 / 720.0) + x2 * F32(1.0 / 40320.0))))
    return s, c


@_inlined
def cosine_direction(u1, u2):
    """A cosine-weighted direction about +z from two uniform draws (Shirley–Chiu's concentric
    disk, lifted): (x, y, z) with z = cos θ, its pdf z/π. Branch-free, for the vector lanes."""
    a = F32(2.0) * u1 - F32(1.0)
    b = F32(2.0) * u2 - F32(1.0)
    first = abs(a) > abs(b)
    r = a if first else b
    num = b if first else a
    den = a if first else b
    ratio = num / den if den != F32(0.0) else F32(0.0)
    s, c = sin_cos_quarter(_QUARTER_PI * ratio)
    x = r * c if first else r * s
    y = r * s if first else r * c
    z = math.sqrt(max(F32(0.0), F32(1.0) - x * x - y * y))
    return x, y, z


_LOG2E = np.float32(1.4426950408889634)
_LN2 = np.float32(0.6931471805599453)
_SQRT2 = np.float32(1.4142135623730951)


@_inlined
def exp32(x):
    """e^x for x ≤ 0 in float32, branch-free for the vector lanes (libm's call is not): x = (n +
    f)·ln 2 with n whole and |f| ≤ 1/2, e^{f ln 2} by its Taylor polynomial to the 7th power,
    2^n put in the exponent's bits: relative error below 4e-6 on [−87, 0] (float32's rounding of
    x·log₂e; tests/renderer/test_packet.py). Below −87 (float32's least normal number) it returns
    ~2e-38 rather than 0."""
    y = max(x, F32(-87.0)) * _LOG2E
    n = math.floor(y + F32(0.5))
    g = (y - n) * _LN2
    p = F32(1.0) + g * (F32(1.0) + g * (F32(0.5) + g * (F32(1.0 / 6.0) + g * (
        F32(1.0 / 24.0) + g * (F32(1.0 / 120.0) + g * (
            F32(1.0 / 720.0) + g * F32(1.0 / 5040.0)))))))
    return p * np.int32((np.int32(n) + np.int32(127)) << np.int32(23)).view(np.float32)


@_inlined
def log32(x):
    """ln x for a normal positive float32, branch-free: the exponent's bits, and the mantissa m
    moved into [√½, √2) by ln m = 2 atanh((m − 1)/(m + 1)), its odd series to the 11th power:
    absolute error below 2e-6 on [2⁻²⁴, 1] (tests/renderer/test_packet.py)."""
    i = np.float32(x).view(np.int32)
    e = ((i >> np.int32(23)) & np.int32(255)) - np.int32(127)
    m = np.int32((i & np.int32(0x7FFFFF)) | np.int32(0x3F800000)).view(np.float32)
    big = m > _SQRT2
    m = m * F32(0.5) if big else m
    e = e + np.int32(1) if big else e
    r = (m - F32(1.0)) / (m + F32(1.0))
    r2 = r * r
    series = F32(2.0) * r * (F32(1.0) + r2 * (F32(1.0 / 3.0) + r2 * (F32(1.0 / 5.0) + r2 * (
        F32(1.0 / 7.0) + r2 * (F32(1.0 / 9.0) + r2 * F32(1.0 / 11.0))))))
    return F32(e) * _LN2 + series


_M1 = np.uint32(0x55555555)
_M2 = np.uint32(0x33333333)
_M4 = np.uint32(0x0F0F0F0F)
_M8 = np.uint32(0x00FF00FF)
_LK1 = np.uint32(0x6C50B47C)
_LK2 = np.uint32(0xB82F1E52)
_LK3 = np.uint32(0xC7AFE638)
_LK4 = np.uint32(0x8D22F6E6)


@_inlined
def reverse32(x):
    """``renderer.rng.reverse_bits32`` in 32-bit lanes."""
    x = np.uint32(((x >> np.uint32(1)) & _M1) | ((x & _M1) << np.uint32(1)))
    x = np.uint32(((x >> np.uint32(2)) & _M2) | ((x & _M2) << np.uint32(2)))
    x = np.uint32(((x >> np.uint32(4)) & _M4) | ((x & _M4) << np.uint32(4)))
    x = np.uint32(((x >> np.uint32(8)) & _M8) | ((x & _M8) << np.uint32(8)))
    return np.uint32((x >> np.uint32(16)) | (x << np.uint32(16)))


@_inlined
def laine_karras32(x, seed):
    """``renderer.rng._laine_karras`` in 32-bit lanes."""
    x = np.uint32(x + seed)
    x = np.uint32(x ^ np.uint32(x * _LK1))
    x = np.uint32(x ^ np.uint32(x * _LK2))
    x = np.uint32(x ^ np.uint32(x * _LK3))
    return np.uint32(x ^ np.uint32(x * _LK4))


_S1 = np.uint32(0xAAAAAAAA)
_S2 = np.uint32(0xCCCCCCCC)
_S4 = np.uint32(0xF0F0F0F0)
_S8 = np.uint32(0xFF00FF00)
_S16 = np.uint32(0xFFFF0000)


@_inlined
def pascal32(y):
    """Sobol' dimension 2 (the Pascal matrix mod 2) of the index whose bit reversal is y, bit
    reversed: by Lucas' theorem C(k, j) is odd iff j's bits are a subset of k's, so bit j of the
    value is the XOR of y's bits k ⊇ j, a superset sum in five shift-and-XOR steps (the scalar
    kernel's ``_linear_map(_PASCAL_REVERSED, ·)`` of the unreversed index, without its table
    lookups, which keep LLVM from vectorizing the loop: it cannot bound a gather's addresses)."""
    y = np.uint32(y ^ ((y & _S1) >> np.uint32(1)))
    y = np.uint32(y ^ ((y & _S2) >> np.uint32(2)))
    y = np.uint32(y ^ ((y & _S4) >> np.uint32(4)))
    y = np.uint32(y ^ ((y & _S8) >> np.uint32(8)))
    return np.uint32(y ^ ((y & _S16) >> np.uint32(16)))


@_inlined
def sobol_pair32(reversed_index, shuffle, scramble0, scramble1):
    """Components 0 and 1 of a point of the shuffled, scrambled (0,2)-sequence
    (``renderer.rng.sobol_value``, to float32's 24 bits), from the point's reversed index."""
    y0 = reverse32(laine_karras32(reversed_index, shuffle))
    u0 = reverse32(laine_karras32(y0, scramble0))
    u1 = reverse32(laine_karras32(pascal32(y0), scramble1))
    return (np.float32(u0 >> np.uint32(8)) * _TWO_POW_M24,
            np.float32(u1 >> np.uint32(8)) * _TWO_POW_M24)


@_inlined
def _lane_seed(SD, block, vertex, lane, c):
    """Seed c of the lane's block at vertex 0 or 1 (the two loaded as vectors, then selected)."""
    a = SD[(3 * (1 + block) + c) * LANES + lane]
    b = SD[(3 * (6 + block) + c) * LANES + lane]
    return a if vertex == 0 else b


@kernel
def _sobol_stage(P, Q, SD):
    """Under the sobol sampler, each lane's light pick, point on the light and direction at its
    vertex (rows U_PICK … U_B2), for the lanes at one of the first SOBOL_VERTICES vertices (the
    others compute vertex 1's values, unused)."""
    for lane in range(LANES):
        vertex = min(Q[DEPTH + lane], np.int32(SOBOL_VERTICES - 1))
        r = reverse32(np.uint32(Q[SIDX + lane]))
        P[U_PICK + lane], _ = sobol_pair32(r, _lane_seed(SD, 0, vertex, lane, 0),
                                           _lane_seed(SD, 0, vertex, lane, 1),
                                           _lane_seed(SD, 0, vertex, lane, 1))
        P[U_L1 + lane], P[U_L2 + lane] = sobol_pair32(
            r, _lane_seed(SD, 1, vertex, lane, 0), _lane_seed(SD, 1, vertex, lane, 1),
            _lane_seed(SD, 1, vertex, lane, 2))
        P[U_B1 + lane], P[U_B2 + lane] = sobol_pair32(
            r, _lane_seed(SD, 3, vertex, lane, 0), _lane_seed(SD, 3, vertex, lane, 1),
            _lane_seed(SD, 3, vertex, lane, 2))


@kernel
def _closest(P, Q, prims, eps):
    """Every primitive against the packet's rays: T_HIT and HIT (−1: none)."""
    for lane in range(LANES):
        P[T_HIT + lane] = _INF
        Q[HIT + lane] = -1
    for q in range(prims.shape[1]):
        g = _prim(prims, q)
        for lane in range(LANES):
            ok, t = _lane_hit(P, lane, DX, g, eps, P[T_HIT + lane])
            P[T_HIT + lane] = t if ok else P[T_HIT + lane]
            Q[HIT + lane] = q if ok else Q[HIT + lane]


@_inlined
def _prim(prims, q):
    """Primitive q's corner, edges and triangle flag, loaded once for all the lanes."""
    return (prims[0, q], prims[1, q], prims[2, q], prims[3, q], prims[4, q], prims[5, q],
            prims[6, q], prims[7, q], prims[8, q], prims[19, q])


@_inlined
def _lane_hit(P, lane, d, g, eps, far):
    """(hit, t): the lane's ray from (OX, OY, OZ) along rows d, d + 1, d + 2 of the packet
    against the primitive ``g`` (``_prim``), between eps and far."""
    t, u, v = _plane_hit(P[OX + lane], P[OY + lane], P[OZ + lane], P[d + lane],
                         P[d + LANES + lane], P[d + 2 * LANES + lane],
                         g[0], g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8])
    tri = g[9]
    ok = ((u >= F32(0.0)) & (v >= F32(0.0)) & (u + tri * v <= F32(1.0))
          & (v + tri * u <= F32(1.0)) & (t > eps) & (t < far))
    return ok, t


@_inlined
def _plane_hit(ox, oy, oz, dx, dy, dz, o0, o1, o2, a0, a1, a2, b0, b1, b2):
    """Möller–Trumbore's (t, u, v) of a ray and the plane of a parallelogram or triangle (corner
    o, edges a, b); a ray parallel to it gets non-finite values, which fail every test."""
    px = dy * b2 - dz * b1
    py = dz * b0 - dx * b2
    pz = dx * b1 - dy * b0
    inv = F32(1.0) / (a0 * px + a1 * py + a2 * pz)
    t0, t1, t2 = ox - o0, oy - o1, oz - o2
    u = (t0 * px + t1 * py + t2 * pz) * inv
    q0 = t1 * a2 - t2 * a1
    q1 = t2 * a0 - t0 * a2
    q2 = t0 * a1 - t1 * a0
    v = (dx * q0 + dy * q1 + dz * q2) * inv
    t = (b0 * q0 + b1 * q1 + b2 * q2) * inv
    return t, u, v


@kernel
def _gather(P, Q, rng, prims, light_prim, light_cdf, sobol, media):
    """Each lane's hit primitive's columns (a miss reads primitive 0's, masked later; with
    ``media`` its medium's too) and a light picked by power, with its columns (a scene of one
    light: none to pick, its columns written once, by the first call). ``sobol``: the pick of
    the first vertices is U_PICK's."""
    for lane in range(LANES):  # indexed loads: scalar (LLVM cannot bound their addresses)
        h = max(Q[HIT + lane], 0)
        P[NX + lane], P[NY + lane], P[NZ + lane] = prims[9, h], prims[10, h], prims[11, h]
        P[AR + lane], P[AG + lane], P[AB + lane] = prims[12, h], prims[13, h], prims[14, h]
        P[ER + lane], P[EG + lane], P[EB + lane] = prims[15, h], prims[16, h], prims[17, h]
        P[E_PA + lane] = prims[18, h]
    if media:  # (the medium's own columns: _enter's, for the lanes that go in)
        for lane in range(LANES):
            h = max(Q[HIT + lane], 0)
            P[HSS + lane], P[HSF + lane] = prims[SINGLE, h], prims[FRACTION, h]
    n_lights = light_cdf.shape[0]
    for lane in range(LANES):
        li = 0
        if n_lights > 1:
            z = _step(rng[lane])
            rng[lane] = z
            u = float(_float(z))
            if sobol and Q[DEPTH + lane] < SOBOL_VERTICES:
                u = float(P[U_PICK + lane])
            while li < n_lights - 1 and u >= light_cdf[li]:
                li += 1
        q = light_prim[li]
        if Q[LIGHT + lane] == q:
            continue  # its columns are there from before
        Q[LIGHT + lane] = q
        for k in range(9):
            P[QOX + k * LANES + lane] = prims[k, q]
        P[QNX + lane], P[QNY + lane], P[QNZ + lane] = prims[9, q], prims[10, q], prims[11, q]
        P[QER + lane], P[QEG + lane], P[QEB + lane] = prims[15, q], prims[16, q], prims[17, q]
        P[Q_PA + lane], P[Q_TRI + lane] = prims[18, q], prims[19, q]


@_inlined
def _about(lx, ly, lz, nx, ny, nz):
    """The direction (lx, ly, lz) of the frame about the unit vector n (z along n) in world
    coordinates: Duff et al.'s branch-free orthonormal basis."""
    sign = F32(1.0) if nz >= F32(0.0) else F32(-1.0)
    a = F32(-1.0) / (sign + nz)
    b = nx * ny * a
    return (lx * (F32(1.0) + sign * nx * nx * a) + ly * b + lz * nx,
            lx * (sign * b) + ly * (sign + ny * ny * a) + lz * ny,
            lx * (-sign * nx) + ly * (-ny) + lz * nz)


@_inlined
def _draws(P, rng, lane, stratified):
    """The lane's six draws of a vertex: the light point's two, the direction's two, the
    roulette's, one more (a single_scatter surface's choice); ``stratified``: the first four are
    the sobol stage's."""
    z = _step(rng[lane])
    u1 = _float(z)
    z = _step(z)
    u2 = _float(z)
    z = _step(z)
    u3 = _float(z)
    z = _step(z)
    u4 = _float(z)
    z = _step(z)
    u5 = _float(z)
    z = _step(z)
    u6 = _float(z)
    rng[lane] = z
    u1 = P[U_L1 + lane] if stratified else u1
    u2 = P[U_L2 + lane] if stratified else u2
    u3 = P[U_B1 + lane] if stratified else u3
    u4 = P[U_B2 + lane] if stratified else u4
    return u1, u2, u3, u4, u5, u6


@_inlined
def _light_point(P, lane, u1, u2, px, py, pz):
    """A point on the light picked in _gather (a triangle's: the parallelogram's folded), seen
    from (px, py, pz): its direction, squared distance, distance, cosine at the light, and the
    sample's solid-angle density times that cosine (pmf / area × distance²)."""
    fold = (P[Q_TRI + lane] > F32(0.0)) & (u1 + u2 > F32(1.0))
    s1 = F32(1.0) - u1 if fold else u1
    s2 = F32(1.0) - u2 if fold else u2
    wx = P[QOX + lane] + s1 * P[QAX + lane] + s2 * P[QBX + lane] - px
    wy = P[QOY + lane] + s1 * P[QAY + lane] + s2 * P[QBY + lane] - py
    wz = P[QOZ + lane] + s1 * P[QAZ + lane] + s2 * P[QBZ + lane] - pz
    d2 = wx * wx + wy * wy + wz * wz
    dist = math.sqrt(d2)
    inv = F32(1.0) / dist
    wx, wy, wz = wx * inv, wy * inv, wz * inv
    cos_l = -(P[QNX + lane] * wx + P[QNY + lane] * wy + P[QNZ + lane] * wz)
    return wx, wy, wz, d2, dist, cos_l, P[Q_PA + lane] * d2


@kernel
def _shade(P, Q, rng, eps, max_depth, sobol, media):
    """Emission seen, the light sample and its shadow ray, the next direction, the roulette;
    ``sobol``: the first vertices' light point and direction are the sobol stage's. With
    ``media``: a lane whose segment ended at a medium's event (EVENT, ``_scatter``'s) is left as
    it is, and a single_scatter surface is crossed straight on (always on the way out, with
    probability 1 − surface_fraction on the way in) or else reflects as a diffuse surface."""
    for lane in range(LANES):
        miss = Q[HIT + lane] < 0
        event = media & (Q[EVENT + lane] != 0)
        t = P[T_HIT + lane]
        dx, dy, dz = P[DX + lane], P[DY + lane], P[DZ + lane]
        nx, ny, nz = P[NX + lane], P[NY + lane], P[NZ + lane]
        cos_d = nx * dx + ny * dy + nz * dz
        hx = P[OX + lane] + t * dx
        hy = P[OY + lane] + t * dy
        hz = P[OZ + lane] + t * dz
        # emission, on the normal's side only; weighted against the light sample that could
        # have found it from the last scattering vertex (none at the camera: PDF_B 0)
        # (pdf_l = a / c, the weight pdf_b² / (pdf_b² + pdf_l²) with c² multiplied in: one
        # division, not two; a surface that does not emit has a = 0 and weight 1)
        pdf_b = P[PDF_B + lane]
        ex, ey, ez = hx - P[PPX + lane], hy - P[PPY + lane], hz - P[PPZ + lane]
        a = P[E_PA + lane] * (ex * ex + ey * ey + ez * ez)
        bc = pdf_b * max(-cos_d, _COS_MIN)
        w = F32(1.0) if (pdf_b == F32(0.0)) | (a == F32(0.0)) else bc * bc / (bc * bc + a * a)
        seen = (cos_d < F32(0.0)) & (not miss) & (not event)
        P[LR + lane] += P[TR + lane] * P[ER + lane] * w if seen else F32(0.0)
        P[LG + lane] += P[TG + lane] * P[EG + lane] * w if seen else F32(0.0)
        P[LB + lane] += P[TB + lane] * P[EB + lane] * w if seen else F32(0.0)
        depth = Q[DEPTH + lane]
        last = (max_depth >= np.int32(0)) & (depth >= max_depth)
        # the surface facing the ray, the next origin off it
        side = F32(-1.0) if cos_d > F32(0.0) else F32(1.0)
        nx, ny, nz = nx * side, ny * side, nz * side
        px = hx + nx * eps
        py = hy + ny * eps
        pz = hz + nz * eps
        u1, u2, u3, u4, u5, u6 = _draws(P, rng, lane, sobol & (depth < np.int32(SOBOL_VERTICES)))
        # a single_scatter surface let through: out always, in with probability 1 − fraction
        cross = (media & (P[HSS + lane] > F32(0.0)) & (not miss) & (not event)
                 & ((cos_d > F32(0.0)) | (u6 >= P[HSF + lane])))
        keep = event | cross
        wx, wy, wz, d2, dist, cos_l, a_l = _light_point(P, lane, u1, u2, px, py, pz)
        cos_s = nx * wx + ny * wy + nz * wz
        # the power heuristic's weight × (cos / π) / pdf: pdf_l pdf_b / (pdf_l² + pdf_b²) / pdf_l
        # with pdf_l = a_l / c_l, pdf_b = cos/π, c_l² multiplied in
        c_l = max(cos_l, _COS_MIN)
        bc = cos_s * _INV_PI * c_l
        f = a_l * bc / (a_l * a_l + bc * bc)
        lit = ((cos_s > F32(0.0)) & (cos_l > F32(0.0)) & (not miss) & (not last)
               & (d2 > F32(0.0)) & (not keep))
        # (an event's lane: _scatter writes its own light sample over these)
        P[CR + lane] = P[TR + lane] * P[AR + lane] * P[QER + lane] * f if lit else F32(0.0)
        P[CG + lane] = P[TG + lane] * P[AG + lane] * P[QEG + lane] * f if lit else F32(0.0)
        P[CB + lane] = P[TB + lane] * P[AB + lane] * P[QEB + lane] * f if lit else F32(0.0)
        P[SX + lane], P[SY + lane], P[SZ + lane] = wx, wy, wz
        P[S_DIST + lane] = dist - eps
        Q[OCCLUDED + lane] = 0 if lit else 1
        # the next direction, cosine-weighted about the normal
        lx, ly, lz = cosine_direction(u3, u4)
        vx, vy, vz = _about(lx, ly, lz, nx, ny, nz)
        P[DX + lane] = dx if keep else vx
        P[DY + lane] = dy if keep else vy
        P[DZ + lane] = dz if keep else vz
        P[PDF_B + lane] = pdf_b if keep else lz * _INV_PI
        # a crossing goes on from the far side of the surface
        P[OX + lane] = P[OX + lane] if event else (hx - nx * eps if cross else px)
        P[OY + lane] = P[OY + lane] if event else (hy - ny * eps if cross else py)
        P[OZ + lane] = P[OZ + lane] if event else (hz - nz * eps if cross else pz)
        P[PPX + lane] = P[PPX + lane] if keep else px
        P[PPY + lane] = P[PPY + lane] if keep else py
        P[PPZ + lane] = P[PPZ + lane] if keep else pz
        br = P[TR + lane] * P[AR + lane]
        bg = P[TG + lane] * P[AG + lane]
        bb = P[TB + lane] * P[AB + lane]
        depth_next = depth + np.int32(1)
        q = min(max(br, max(bg, bb)), _RR_MAX)
        roulette = depth_next >= _RR_DEPTH
        scale = F32(1.0) / q if roulette else F32(1.0)
        P[TR + lane] = P[TR + lane] if keep else br * scale
        P[TG + lane] = P[TG + lane] if keep else bg * scale
        P[TB + lane] = P[TB + lane] if keep else bb * scale
        Q[DEPTH + lane] = depth if keep else depth_next
        # (a path that carries nothing ends, as the scalar kernel's: a black surface)
        ends = miss | last | (roulette & (u5 >= q)) | (q == F32(0.0))
        Q[DEAD + lane] = Q[DEAD + lane] if event else (0 if cross else (1 if ends else 0))
        # a crossing's direction (``_enter``: the medium the ray goes on in)
        Q[CROSS + lane] = (1 if cos_d < F32(0.0) else -1) if cross else 0


@kernel
def _enter(P, Q, prims):
    """After ``_shade``, where a lane crossed a single_scatter surface: going in, the lane takes
    the medium's parameters from the primitive's columns (its event still to come); going out,
    it leaves the medium. A stage of its own, run only when some lane crossed: in ``_shade``'s
    loop these stores kept LLVM from vectorizing it."""
    for lane in range(LANES):
        cross = Q[CROSS + lane]
        if cross < 0:
            Q[IN_MED + lane] = 0
        elif cross > 0:
            h = Q[HIT + lane]
            Q[IN_MED + lane] = 1
            Q[DONE + lane] = 0
            P[MSIG + lane], P[MG + lane] = prims[SIGMA, h], prims[PHASE_G, h]
            P[MAR + lane], P[MAG + lane], P[MAB + lane] = prims[12, h], prims[13, h], prims[14, h]


@kernel
def _flight(P, Q, rng):
    """Inside a single_scatter medium: before its event, a free flight from exp(−σt·s) that may
    end short of the surface (EVENT, FLIGHT its length); after it, the segment's attenuation
    exp(−σt·t)."""
    for lane in range(LANES):
        inside = (Q[IN_MED + lane] != 0) & (Q[DEAD + lane] == 0)
        done = Q[DONE + lane] != 0
        t = P[T_HIT + lane]
        after = inside & done
        attenuation = exp32(-P[MSIG + lane] * t) if after else F32(1.0)
        P[TR + lane] *= attenuation
        P[TG + lane] *= attenuation
        P[TB + lane] *= attenuation
        z = _step(rng[lane])
        rng[lane] = z
        s = -log32(F32(1.0) - _float(z)) / max(P[MSIG + lane], F32(1e-30))
        P[FLIGHT + lane] = s
        Q[EVENT + lane] = 1 if inside & (not done) & (s < t) else 0


@_inlined
def hg_pdf32(cos_theta, g):
    """Henyey–Greenstein's density (``renderer.materials.phase.hg_pdf``: isotropic below
    ``ISOTROPIC_G``, as ``hg_direction`` samples)."""
    den = F32(1.0) + g * g - F32(2.0) * g * cos_theta
    pdf = _INV_4PI * (F32(1.0) - g * g) / (den * math.sqrt(den))
    return pdf if abs(g) >= F32(ISOTROPIC_G) else _INV_4PI


@_inlined
def hg_direction(u1, u2, g):
    """A direction from Henyey–Greenstein's phase function about +z, (x, y, z = cos θ), from two
    uniform draws, branch-free: the concentric map's uniform point of the disk gives the angle
    φ and an independent uniform r², which the phase function's inverse cdf turns into cos θ
    (``renderer.materials.phase.hg_sample_cos``; isotropic below ``ISOTROPIC_G``)."""
    a, b, _ = cosine_direction(u1, u2)
    r2 = a * a + b * b
    r = math.sqrt(r2)
    cphi = a / r if r > F32(0.0) else F32(1.0)
    sphi = b / r if r > F32(0.0) else F32(0.0)
    gg = g if abs(g) >= F32(ISOTROPIC_G) else F32(ISOTROPIC_G)
    h = (F32(1.0) - gg * gg) / (F32(1.0) - gg + F32(2.0) * gg * r2)
    hg = min(F32(1.0), max(F32(-1.0), (F32(1.0) + gg * gg - h * h) / (F32(2.0) * gg)))
    cos_t = hg if abs(g) >= F32(ISOTROPIC_G) else F32(1.0) - F32(2.0) * r2
    sin_t = math.sqrt(max(F32(0.0), F32(1.0) - cos_t * cos_t))
    return sin_t * cphi, sin_t * sphi, cos_t


@kernel
def _scatter(P, Q, rng, eps, max_depth, sobol):
    """The lanes whose flight ended at the medium's one event (``renderer.integrators.subsurface
    .volumetric.medium_segment`` with single_scatter's medium, grey): the albedo, a light sample
    from the event MIS-weighted against the phase function (its shadow ray leaves through the
    medium: ``_shadow_media``), the phase function's direction, the roulette (capped at 1 in a
    medium, as the scalar kernel's)."""
    for lane in range(LANES):
        if Q[EVENT + lane] == 0:
            continue
        depth = Q[DEPTH + lane]
        s = P[FLIGHT + lane]
        dx, dy, dz = P[DX + lane], P[DY + lane], P[DZ + lane]
        px = P[OX + lane] + s * dx
        py = P[OY + lane] + s * dy
        pz = P[OZ + lane] + s * dz
        g = P[MG + lane]
        br = P[TR + lane] * P[MAR + lane]
        bg = P[TG + lane] * P[MAG + lane]
        bb = P[TB + lane] * P[MAB + lane]
        u1, u2, u3, u4, u5, _ = _draws(P, rng, lane, sobol & (depth < np.int32(SOBOL_VERTICES)))
        if max_depth >= 0 and depth >= max_depth:
            Q[DEAD + lane] = 1
            Q[OCCLUDED + lane] = 1
            continue
        # the light sample
        wx, wy, wz, d2, dist, cos_l, a_l = _light_point(P, lane, u1, u2, px, py, pz)
        # phase · the power heuristic's weight / pdf_l, as in _shade: one division
        bc = hg_pdf32(dx * wx + dy * wy + dz * wz, g) * max(cos_l, _COS_MIN)
        f = a_l * bc / (a_l * a_l + bc * bc)
        lit = (cos_l > F32(0.0)) & (d2 > F32(0.0))
        P[CR + lane] = br * P[QER + lane] * f if lit else F32(0.0)
        P[CG + lane] = bg * P[QEG + lane] * f if lit else F32(0.0)
        P[CB + lane] = bb * P[QEB + lane] * f if lit else F32(0.0)
        P[SX + lane], P[SY + lane], P[SZ + lane] = wx, wy, wz
        P[S_DIST + lane] = dist - eps
        Q[OCCLUDED + lane] = 0 if lit else 1
        # the phase function's direction about d
        lx, ly, lz = hg_direction(u3, u4, g)
        P[DX + lane], P[DY + lane], P[DZ + lane] = _about(lx, ly, lz, dx, dy, dz)
        P[PDF_B + lane] = hg_pdf32(lz, g)
        P[OX + lane], P[OY + lane], P[OZ + lane] = px, py, pz
        P[PPX + lane], P[PPY + lane], P[PPZ + lane] = px, py, pz
        depth += np.int32(1)
        q = min(max(br, max(bg, bb)), F32(1.0))
        roulette = depth >= _RR_DEPTH
        scale = F32(1.0) / q if roulette else F32(1.0)
        P[TR + lane], P[TG + lane], P[TB + lane] = br * scale, bg * scale, bb * scale
        Q[DEPTH + lane] = depth
        Q[DONE + lane] = 1
        Q[DEAD + lane] = 1 if (roulette & (u5 >= q)) | (q == F32(0.0)) else 0


@kernel
def _shadow(P, Q, prims, eps):
    """Every primitive against the packet's shadow rays: OCCLUDED."""
    for q in range(prims.shape[1]):
        g = _prim(prims, q)
        for lane in range(LANES):
            ok, _ = _lane_hit(P, lane, SX, g, eps, P[S_DIST + lane])
            Q[OCCLUDED + lane] = 1 if ok else Q[OCCLUDED + lane]


@kernel
def _shadow_media(P, Q, prims, eps):
    """``_shadow`` in a scene with single_scatter media: a single_scatter surface lets the shadow
    ray through, and the optical depth of the media it crosses is summed as
    ``renderer.integrators.shadow.flat_transmittance`` sums it (leaving a medium at t adds σt·t,
    entering one takes σt·t off, the media open at the end add σt·length; each entry lets
    1 − surface_fraction in). The media are grey: one sum, not three."""
    for lane in range(LANES):
        inside = Q[IN_MED + lane] != 0
        P[TAU + lane] = F32(0.0)
        P[OPEN + lane] = P[MSIG + lane] if inside else F32(0.0)
        Q[N_OPEN + lane] = 1 if inside else 0
        P[STR + lane] = F32(1.0)
    for q in range(prims.shape[1]):
        g = _prim(prims, q)
        passable = prims[SINGLE, q] > F32(0.0)
        qnx, qny, qnz = prims[9, q], prims[10, q], prims[11, q]
        let_in = F32(1.0) - prims[FRACTION, q]
        sigma = prims[SIGMA, q]
        for lane in range(LANES):
            ok, t = _lane_hit(P, lane, SX, g, eps, P[S_DIST + lane])
            Q[OCCLUDED + lane] = 1 if ok & (not passable) else Q[OCCLUDED + lane]
            cross = ok & passable
            enters = (P[SX + lane] * qnx + P[SY + lane] * qny + P[SZ + lane] * qnz) < F32(0.0)
            signed = -sigma if enters else sigma
            P[TAU + lane] += signed * t if cross else F32(0.0)
            P[OPEN + lane] -= signed if cross else F32(0.0)
            Q[N_OPEN + lane] += (np.int32(1) if enters else np.int32(-1)) if cross else np.int32(0)
            P[STR + lane] *= let_in if cross & enters else F32(1.0)


@kernel
def _add_light_media(P, Q):
    """``_add_light`` times the shadow ray's transmittance (``_shadow_media``'s sums)."""
    for lane in range(LANES):
        free = Q[OCCLUDED + lane] == 0
        length = P[S_DIST + lane] if Q[N_OPEN + lane] > 0 else F32(0.0)
        tr = P[STR + lane] * exp32(-max(P[TAU + lane] + P[OPEN + lane] * length, F32(0.0)))
        P[LR + lane] += P[CR + lane] * tr if free else F32(0.0)
        P[LG + lane] += P[CG + lane] * tr if free else F32(0.0)
        P[LB + lane] += P[CB + lane] * tr if free else F32(0.0)


@kernel
def _add_light(P, Q):
    for lane in range(LANES):
        free = Q[OCCLUDED + lane] == 0
        P[LR + lane] += P[CR + lane] if free else F32(0.0)
        P[LG + lane] += P[CG + lane] if free else F32(0.0)
        P[LB + lane] += P[CB + lane] if free else F32(0.0)


@kernel
def packet_rows(prims, light_prim, light_cdf, cam, width, height, seed, max_depth, eps, x0, y0,
                tile_w, tile_h, next_row, sample_start, counts, out_sum, out_sum_sq,
                out_count, out_dropped, out_segments, sobol, media, P, Q, rng, lane_pixel, SD,
                sob, seed_pixel):
    """The paths of the rows of a tile this thread claims (``claim_row`` on ``next_row``, int64
    (1,), which the pass's threads share; the next when it has handed out the last path of
    one), a packet at a time: each pixel's samples [sample_start, sample_start + counts[pixel])
    in turn. Under the
    ``sobol`` sampler, ``sob`` (SOBOL_BLOCKS, 3) holds the sequence seeds of the pixel the
    thread is at, ``SD`` (SEED_ROWS × LANES) those of each lane's, ``seed_pixel`` (LANES) whose
    they are."""
    row = claim_row(next_row)
    col = 0
    s = 0
    live = 0
    sob_pixel = -1
    key_pixel = -1
    key_of_pixel = np.uint64(0)
    for lane in range(LANES):
        Q[DEAD + lane] = 1
        Q[LIGHT + lane] = -1
        lane_pixel[lane] = -1
        seed_pixel[lane] = -1
    while True:
        for lane in range(LANES):
            if Q[DEAD + lane] == 0:
                continue
            if lane_pixel[lane] >= 0:  # the path ended: its sample to the tile's buffer
                ty, tx = lane_pixel[lane] // tile_w, lane_pixel[lane] % tile_w
                add_sample(out_sum, out_sum_sq, out_count, out_dropped, ty, tx,
                           float(P[LR + lane]), float(P[LG + lane]), float(P[LB + lane]))
                out_segments[ty, tx] += Q[SEGMENTS + lane]
                lane_pixel[lane] = -1
                live -= 1
            # the next path of this thread's pixels, if any
            while row < tile_h and s >= counts[row, col]:
                s = 0
                col += 1
                if col == tile_w:
                    col = 0
                    row = claim_row(next_row)
            if row >= tile_h:
                continue
            x, y = x0 + col, y0 + row
            index = sample_start + s
            s += 1
            pixel = y * width + x
            if key_pixel != pixel:  # sample_key's pixel part, once a pixel
                key_of_pixel = pixel_key(seed, pixel)
                key_pixel = pixel
            key = key_of_sample(key_of_pixel, index)
            z = _step(np.uint32((key ^ (key >> np.uint64(32))) & np.uint64(0xFFFFFFFF)))
            jx = float(_float(z))
            z = _step(z)
            jy = float(_float(z))
            rng[lane] = z
            if sobol:
                if sob_pixel != pixel:  # the thread's next pixel: its sequences' seeds
                    sobol_block_seeds(mix64(key_of_sample(key_of_pixel, 0) ^ PIXEL_SEED_SALT),
                                      sob)
                    sob_pixel = pixel
                if seed_pixel[lane] != pixel:
                    for b in range(SOBOL_BLOCKS):
                        for c in range(3):
                            SD[(3 * b + c) * LANES + lane] = np.uint32(sob[b, c])
                    seed_pixel[lane] = pixel
                jx = sobol_value(index, sob[0, 0], sob[0, 1], 0)
                jy = sobol_value(index, sob[0, 0], sob[0, 2], 1)
                Q[SIDX + lane] = np.int32(index)
            o, d = camera_ray(cam, width, height, x, y, jx, jy)
            P[OX + lane], P[OY + lane], P[OZ + lane] = o
            P[DX + lane], P[DY + lane], P[DZ + lane] = d
            P[TR + lane], P[TG + lane], P[TB + lane] = F32(1.0), F32(1.0), F32(1.0)
            P[LR + lane], P[LG + lane], P[LB + lane] = F32(0.0), F32(0.0), F32(0.0)
            P[PDF_B + lane] = F32(0.0)
            P[PPX + lane], P[PPY + lane], P[PPZ + lane] = o
            Q[IN_MED + lane] = 0
            Q[DONE + lane] = 0
            Q[EVENT + lane] = 0
            Q[DEPTH + lane] = 0
            Q[SEGMENTS + lane] = 0
            Q[DEAD + lane] = 0
            lane_pixel[lane] = row * tile_w + col
            live += 1
        if live == 0:
            return
        for lane in range(LANES):
            Q[SEGMENTS + lane] += 1 - Q[DEAD + lane]
        _closest(P, Q, prims, eps)
        if sobol:
            _sobol_stage(P, Q, SD)
        _gather(P, Q, rng, prims, light_prim, light_cdf, sobol, media)
        if media:  # each medium stage only where some lane needs it
            inside = 0
            for lane in range(LANES):
                inside += Q[IN_MED + lane]
                Q[EVENT + lane] = 0
            if inside > 0:
                _flight(P, Q, rng)
        _shade(P, Q, rng, eps, np.int32(max_depth), sobol, media)
        if media:
            crossed = 0
            events = 0
            for lane in range(LANES):
                crossed += Q[CROSS + lane] != 0
                events += Q[EVENT + lane]
            if crossed > 0:
                _enter(P, Q, prims)
            if events > 0:
                _scatter(P, Q, rng, eps, np.int32(max_depth), sobol)
            _shadow_media(P, Q, prims, eps)
            _add_light_media(P, Q)
        else:
            _shadow(P, Q, prims, eps)
            _add_light(P, Q)
        # lanes with no path (the thread's pixels done) stay dead, their sample unwritten
        for lane in range(LANES):
            if lane_pixel[lane] < 0:
                Q[DEAD + lane] = 1


def render_tile_packet(scene, x0: int, y0: int, width: int, height: int, sample_start: int,
                       counts: np.ndarray) -> SampleBuffer:
    """``render_tile`` (arguments checked there) by the packet kernel; ``counts`` (height, width)
    int32: each pixel's samples, the first of [sample_start, …)."""
    S = scene.arrays
    buf = SampleBuffer.empty(x0, y0, width, height)
    if not width or not height or not counts.any():
        return buf
    prims = scene.derived("prim_columns", prim_columns)
    eps = F32(EPS_REL * scene_scale(scene))
    light_prim = np.ascontiguousarray(S.light_prim, np.int64)
    light_cdf = np.ascontiguousarray(S.light_cdf, np.float64)
    counts = np.ascontiguousarray(counts, np.int32)
    n_chunks = max(1, min(height, numba.get_num_threads()))
    next_row = np.zeros(1, np.int64)

    def chunk(c: int) -> None:
        packet_rows(prims, light_prim, light_cdf, S.camera, scene.width, scene.height,
                    scene.seed, scene.max_depth, eps, x0, y0, width, height, next_row,
                    sample_start, counts, buf.sum, buf.sum_sq, buf.count, buf.dropped,
                    buf.segments, S.sampler[0] == 1, bool(prims[SINGLE].any()),
                    np.zeros(FLOAT_ROWS * LANES, F32),
                    np.zeros(INT_ROWS * LANES, np.int32), np.zeros(LANES, np.uint32),
                    np.zeros(LANES, np.int64), np.zeros(SEED_ROWS * LANES, np.uint32),
                    np.zeros((SOBOL_BLOCKS, 3), np.uint64), np.zeros(LANES, np.int64))

    run_chunks(chunk, n_chunks)
    return buf
