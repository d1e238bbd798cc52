"""Textures and surface parameters (scene format v1.1, "Textures, UVs and shading normals").

A colour parameter (``diffuse.albedo``, ``phong.diffuse`` and ``phong.specular``,
``mirror.reflectance``, ``conductor.specular``) may be a texture, looked up at the hit's (u, v):

- ``bitmap``: the image at (u·su + ou, v·sv + ov), u to the right of the image and v upwards
  ((0, 0) is the bottom-left corner as displayed, the OBJ convention), bilinear between texel
  centres (texel i of W at u = (i + ½)/W) and repeating in both directions: Mitsuba 3's
  ``bitmap`` with ``filter_type: bilinear`` and ``wrap_mode: repeat``.
- ``checkerboard``: ``color0`` where floor(u·su) + floor(v·sv) is even, else ``color1``.

The (u, v) of a hit (``surface_uv``): a quad's (s, t); a box face's (s, t) along the edges
``box_quads`` gives it (renderer.scene.compile); a sphere's u = atan2(d.x, −d.z)/(2π) mod 1,
v = 1 − acos(d.y)/π for the unit direction d from its centre; a triangle's, the mesh's ``uvs``
interpolated by the barycentric coordinates, or, without them, the barycentrics (b1, b2)
themselves, as Mitsuba gives a mesh without texture coordinates.

Arrays (``SceneArrays``): ``tex_param`` (textures, ``TEX_ROW``) a row per texture (slots below);
``texels`` float32, every bitmap's linear texels, row by row from the top, RGB; ``mat_tex``
(materials, 3·``MAX_BINDINGS``) per material the (slot of its row, texture, factor) of each
textured slot, −1 where none; ``prim_uv`` (primitives, 6) the (u, v) of each triangle's three
corners, or no rows when the scene has no textures. The host packs the textures once
(``pack_textures``); ``textured_row`` fills a copy of a textured material's row at a hit.

==========  =====  ===============================================================
Slot        Index  Meaning
==========  =====  ===============================================================
``KIND``    0      ``BITMAP`` or ``CHECKERBOARD``
``OFFSET``  1      bitmap: its first texel's index in ``texels`` (×3 for the float)
``WIDTH``   2      bitmap: texels per row
``HEIGHT``  3      bitmap: rows
``SU``      4–5    scale (su, sv)
``OU``      6–7    bitmap: offset (ou, ov)
``COLOR0``  8–10   checkerboard: color0
``COLOR1``  11–13  checkerboard: color1
==========  =====  ===============================================================
"""

from __future__ import annotations

import math

import numpy as np

from renderer.geometry.shapes import QUAD, SPHERE
from renderer.jit import inline_kernel, kernel
from renderer.materials import translucent
from renderer.materials.bsdf import (
    BACKLIGHT,
    CONDUCTOR,
    DIFFUSE,
    DIFFUSE_ENTRY,
    DIFFUSION,
    MIRROR,
    N_PARAMS,
    PHONG,
    ROUGH_CONDUCTOR,
    ROUGH_DIFFUSE_ENTRY,
    ROUGH_DIFFUSION,
    SINGLE_SCATTER,
)
from renderer.materials.conductor import SPECULAR
from renderer.materials.diffuse import ALBEDO
from renderer.materials.diffusion import profile_from_albedo
from renderer.materials.mirror import REFLECTANCE
from renderer.materials.phong import KD, KS

BITMAP = 0
CHECKERBOARD = 1

KIND, OFFSET, WIDTH, HEIGHT, SU, OU, COLOR0, COLOR1 = 0, 1, 2, 3, 4, 6, 8, 11
TEX_ROW = 14

MAX_BINDINGS = 2  # textured slots of one material (phong's diffuse and specular; backlight's
# albedo and the share of it its surface reflects)

# The slots each colour parameter fills in its material's row, by material kind: (slot, the
# row's slot whose (1 − value) scales it, or −1 for none). A translucent material's textured
# albedo colours its surface: the Lambertian surface of single_scatter, the entry scattering of
# diffuse_entry, backlight's reflected (1 − scale)·albedo and its transmitted term.
PARAM_SLOTS = {DIFFUSE: {"albedo": ((ALBEDO, -1),)},
               PHONG: {"diffuse": ((KD, -1),), "specular": ((KS, -1),)},
               MIRROR: {"reflectance": ((REFLECTANCE, -1),)},
               CONDUCTOR: {"specular": ((SPECULAR, -1),)},
               ROUGH_CONDUCTOR: {"specular": ((SPECULAR, -1),)},
               SINGLE_SCATTER: {"albedo": ((translucent.ALBEDO, -1),)},
               DIFFUSE_ENTRY: {"albedo": ((translucent.ALBEDO, -1),)},
               ROUGH_DIFFUSE_ENTRY: {"albedo": ((translucent.ALBEDO, -1),)},
               BACKLIGHT: {"albedo": ((translucent.ALBEDO, -1),
                                      (translucent.REFLECTED, translucent.SCALE))},
               DIFFUSION: {"albedo": ((translucent.ALBEDO, -1),)},
               ROUGH_DIFFUSION: {"albedo": ((translucent.ALBEDO, -1),)}}
# (diffusion: the albedo at the hit gives the profile's A and d there, ``profile_from_albedo``)

INV_2PI = 1.0 / (2.0 * math.pi)


# --- Host -----------------------------------------------------------------------------------------


def is_texture(value) -> bool:
    return getattr(value, "type", None) in ("bitmap", "checkerboard")


def texture_max(value) -> tuple[float, float, float]:
    """The largest value per channel a colour parameter takes (a triple: itself)."""
    if not is_texture(value):
        return tuple(float(x) for x in value)
    if value.type == "checkerboard":
        return tuple(float(max(a, b)) for a, b in zip(value.color0, value.color1, strict=True))
    return tuple(float(x) for x in value.pixels().reshape(-1, 3).max(axis=0))


def texture_mean(value) -> tuple[float, float, float]:
    """The mean value per channel of a colour parameter over its image (a triple: itself): what
    stands for it where one colour is needed (the material row's slot before a lookup)."""
    if not is_texture(value):
        return tuple(float(x) for x in value)
    if value.type == "checkerboard":
        return tuple(0.5 * (float(a) + float(b))
                     for a, b in zip(value.color0, value.color1, strict=True))
    return tuple(float(x) for x in value.pixels().reshape(-1, 3).mean(axis=0, dtype=np.float64))


def untextured(m):
    """The material with each texture replaced by its mean colour (``texture_mean``)."""
    update = {f: texture_mean(getattr(m, f)) for f in type(m).model_fields
              if is_texture(getattr(m, f))}
    return m.model_copy(update=update) if update else m


def pack_textures(materials, kinds, params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tex_param, texels, mat_tex) of the materials (in row order), their kind tags and
    parameter rows. A bitmap image used by several parameters is packed once."""
    rows: list[np.ndarray] = []
    chunks: list[np.ndarray] = []
    n_texels = 0
    by_image: dict[int, tuple[int, int, int]] = {}  # id(pixels) -> (offset, width, height)
    mat_tex = np.full((len(materials), 3 * MAX_BINDINGS), -1.0)
    for i, (m, kind) in enumerate(zip(materials, kinds, strict=True)):
        b = 0
        for param, slots in PARAM_SLOTS.get(int(kind), {}).items():
            tex = getattr(m, param, None)
            if not is_texture(tex):
                continue
            row = np.zeros(TEX_ROW)
            row[SU:SU + 2] = tex.scale
            if tex.type == "checkerboard":
                row[KIND] = CHECKERBOARD
                row[COLOR0:COLOR0 + 3] = tex.color0
                row[COLOR1:COLOR1 + 3] = tex.color1
            else:
                pixels = tex.pixels()
                if id(pixels) not in by_image:
                    by_image[id(pixels)] = (n_texels, pixels.shape[1], pixels.shape[0])
                    chunks.append(np.ascontiguousarray(pixels, np.float32).reshape(-1))
                    n_texels += pixels.shape[0] * pixels.shape[1]
                row[KIND] = BITMAP
                row[OFFSET], row[WIDTH], row[HEIGHT] = by_image[id(pixels)]
                row[OU:OU + 2] = tex.offset
            for slot, share in slots:
                mat_tex[i, 3 * b:3 * b + 3] = (slot, len(rows),
                                               1.0 if share < 0 else 1.0 - params[i][share])
                b += 1
            rows.append(row)
    tex_param = np.array(rows).reshape(-1, TEX_ROW)
    texels = np.concatenate(chunks) if chunks else np.zeros(0, np.float32)
    return tex_param, texels, mat_tex


# --- Kernels --------------------------------------------------------------------------------------


@kernel
def sphere_uv(n):
    """(u, v) of a sphere at the unit direction n from its centre (scene format v1.1)."""
    u = math.atan2(n[0], -n[2]) * INV_2PI
    if u < 0.0:
        u += 1.0
    return u, 1.0 - math.acos(min(1.0, max(-1.0, n[1]))) / math.pi


@kernel
def surface_uv(kind, prim_uv, prim, u, v, n):
    """The texture coordinates of a hit at the primitive's parameters (u, v) with outward
    normal n: a quad's (s, t), a sphere's ``sphere_uv``, a triangle's interpolated ``uvs`` (its
    barycentrics (b1, b2) when its mesh has none, or the scene no ``prim_uv``)."""
    if kind == SPHERE:
        return sphere_uv(n)
    if kind == QUAD or prim_uv.shape[0] == 0:
        return u, v
    w = 1.0 - u - v
    r = prim_uv[prim]
    return w * r[0] + u * r[2] + v * r[4], w * r[1] + u * r[3] + v * r[5]


@kernel
def _wrap(x, size):
    """x in [0, size): repeating."""
    x = x - size * math.floor(x / size)
    return x if x < size else 0.0


@kernel
def texture_eval(tex_param, texels, t, u, v):
    """The linear RGB of texture t at (u, v)."""
    row = tex_param[t]
    if row[KIND] == CHECKERBOARD:
        su, sv = u * row[SU], v * row[SU + 1]
        if not (math.isfinite(su) and math.isfinite(sv)):
            return row[COLOR0], row[COLOR0 + 1], row[COLOR0 + 2]
        parity = (math.floor(su) + math.floor(sv)) % 2.0
        c = COLOR0 if parity == 0.0 else COLOR1
        return row[c], row[c + 1], row[c + 2]
    w, h = row[WIDTH], row[HEIGHT]
    # Texel centres at (i + ½)/W; row 0 at the top, so v (upwards) counts rows from the bottom
    x = (u * row[SU] + row[OU]) * w - 0.5
    y = (1.0 - (v * row[SU + 1] + row[OU + 1])) * h - 0.5
    if not (math.isfinite(x) and math.isfinite(y)):
        return 0.0, 0.0, 0.0
    x = _wrap(x, w)
    y = _wrap(y, h)
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx, fy = x - x0, y - y0
    iw, ih = int(w), int(h)
    i0, j0 = int(x0), int(y0)
    i1 = i0 + 1 if i0 + 1 < iw else 0
    j1 = j0 + 1 if j0 + 1 < ih else 0
    base = int(row[OFFSET])
    a = 3 * (base + j0 * iw + i0)
    b = 3 * (base + j0 * iw + i1)
    c = 3 * (base + j1 * iw + i0)
    d = 3 * (base + j1 * iw + i1)
    w00, w10, w01, w11 = (1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy
    return (w00 * texels[a] + w10 * texels[b] + w01 * texels[c] + w11 * texels[d],
            w00 * texels[a + 1] + w10 * texels[b + 1] + w01 * texels[c + 1]
            + w11 * texels[d + 1],
            w00 * texels[a + 2] + w10 * texels[b + 2] + w01 * texels[c + 2]
            + w11 * texels[d + 2])


@inline_kernel
def textured_row(S, mat, kind, prim, u, v, n, scratch):
    """Whether material ``mat`` has textures; if so, ``scratch`` holds its row at a hit, each
    textured colour looked up at the hit's (u, v) (a bool, not the row: a kernel without the
    runtime returns no array, tests/renderer/test_jit.py)."""
    if S.mat_tex[mat, 1] < 0.0:
        return False
    for j in range(N_PARAMS):
        scratch[j] = S.mat_param[mat, j]
    tu, tv = surface_uv(kind, S.prim_uv, prim, u, v, n)
    for b in range(MAX_BINDINGS):
        t = int(S.mat_tex[mat, 3 * b + 1])
        if t >= 0:
            slot, k = int(S.mat_tex[mat, 3 * b]), S.mat_tex[mat, 3 * b + 2]
            c = texture_eval(S.tex_param, S.texels, t, tu, tv)
            scratch[slot], scratch[slot + 1], scratch[slot + 2] = k * c[0], k * c[1], k * c[2]
    if S.mat_kind[mat] == DIFFUSION or S.mat_kind[mat] == ROUGH_DIFFUSION:
        profile_from_albedo(scratch)
    return True
