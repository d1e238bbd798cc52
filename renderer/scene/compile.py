"""Compile a validated scene once into the flat arrays the kernels take.

Everything a kernel needs is packed into ``SceneArrays``, a namedtuple of numpy arrays that numba
passes as one argument. Objects become primitives (spheres; quads, with boxes as six outward-facing
quads; triangles, from meshes), ordered by the BVH so each leaf is a contiguous range. Materials
become a tag and a parameter row, lights a table with a power-proportional selection CDF.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, field

import numpy as np

from renderer.environment import build_environment, no_environment
from renderer.geometry.bvh import BVH_WIDTH, MAX_LEAF, build_bvh, stack_size, widen_bvh
from renderer.geometry.flat import FLAT_MAX, FLAT_ROWS, flat_geometry, flat_order
from renderer.geometry.shapes import QUAD, SPHERE, TRIANGLE, prim_bounds, spheres_alone
from renderer.geometry.transform import camera_array, rotation_matrix
from renderer.lights import AREA, BACKGROUND, DIRECTIONAL, ENVIRONMENT, POINT
from renderer.materials.auto import auto_choice, frame_bias
from renderer.materials.bsdf import (
    BACKLIGHT,
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    DIFFUSE_ENTRY,
    DIFFUSION,
    MIRROR,
    N_PARAMS,
    PHONG,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_DIFFUSE_ENTRY,
    ROUGH_DIFFUSION,
    ROUGH_TRANSLUCENT,
    SINGLE_SCATTER,
    TRANSLUCENT,
)
from renderer.materials.conductor import pack_conductor
from renderer.materials.dielectric import IOR, pack_dielectric
from renderer.materials.diffuse import pack_diffuse
from renderer.materials.diffusion import pack_diffusion, pack_opaque
from renderer.materials.mirror import pack_mirror
from renderer.materials.phong import pack_phong
from renderer.materials.translucent import (
    pack_backlight,
    pack_diffuse_entry,
    pack_single_scatter,
    pack_translucent,
)
from renderer.scene.schema import DielectricMaterial
from renderer.textures import pack_textures, untextured
from renderer.vecmath import LUMINANCE, Y_B, Y_G, Y_R

SceneArrays = namedtuple(
    "SceneArrays",
    [
        # BVH (renderer.geometry.bvh)
        "bvh_lo", "bvh_hi", "bvh_child", "bvh_count",
        # a small scene's primitives by column, searched without the tree (renderer.geometry.flat)
        "flat",
        # primitives in BVH order (renderer.geometry.shapes)
        "prim_kind", "prim_geo", "prim_scale", "prim_material", "prim_light",
        # materials (renderer.materials.bsdf)
        "mat_kind", "mat_param",
        # lights (renderer.lights)
        "light_kind", "light_prim", "light_data", "light_cdf", "light_pmf", "env_light",
        # the environment image and its sampling tables (renderer.environment)
        "env_image", "env_marginal", "env_conditional", "env_rotation",
        # camera: position, forward, right, up (unit), tan(fov/2), aspect; background radiance
        "camera", "background",
        # [1] when shadow rays may cross a surface: index-matched media, single-scatter objects
        "null_media",
        # [0] independent samples, [1] the sobol sampler (renderer.rng, render.sampler)
        "sampler",
        # textures (renderer.textures): per triangle its corners' (u, v), per material its
        # textured slots, the textures' rows and texels
        "prim_uv", "mat_tex", "tex_param", "texels",
        # per triangle its corners' shading normals (renderer.materials.shading; NaN: none)
        "prim_normal",
        # per primitive 1 for a sphere of a material with a medium that no other surface enters
        # (renderer.geometry.shapes.spheres_alone: a walk inside asks it alone)
        "prim_alone",
    ],
)


# The material kinds a ray can travel inside of (``trace_path``'s ``medium``)
MEDIUM_KINDS = (TRANSLUCENT, SINGLE_SCATTER, DIFFUSE_ENTRY, ROUGH_TRANSLUCENT, ROUGH_DIFFUSE_ENTRY)


class CompileError(ValueError):
    """A scene that validated but cannot be rendered by this version (e.g. a method not built)."""


@dataclass
class CompiledScene:
    """A scene ready for ``render_tile``: the arrays plus the settings of its ``render`` block."""

    arrays: SceneArrays
    width: int
    height: int
    spp: int
    max_depth: int
    seed: int
    stack_size: int
    target_error: float | None = None
    # With a target: the bias auto's models add to the frame's relMSE, at most
    # (renderer.materials.auto.frame_bias); the loop aims the samples' noise at the target less it
    expected_bias: float = 0.0
    info: dict = field(default_factory=dict)
    # What ``derived`` has computed from ``arrays`` (a replaced copy starts without)
    _derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def derived(self, key: str, fn):
        """``fn(self)``, computed once for these ``arrays`` (the same object; every pass of a
        frame asks the packet kernel's coverage and primitive columns, ~0.3 ms at 64×48 that
        is a tenth of a millisecond frame's pass) and kept on the scene."""
        entry = self._derived.get(key)
        if entry is None or entry[0] is not self.arrays:
            entry = (self.arrays, fn(self))
            self._derived[key] = entry
        return entry[1]


def _luminance(c) -> float:
    return Y_R * c[0] + Y_G * c[1] + Y_B * c[2]


def box_quads(lo, hi, rotate=None, translate=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The six faces of a box as quad rows (origin, edge1, edge2) with outward normals."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    faces = np.array([
        [x0, y0, z0, 0, 0, dz, 0, dy, 0],  # −x
        [x1, y0, z0, 0, dy, 0, 0, 0, dz],  # +x
        [x0, y0, z0, dx, 0, 0, 0, 0, dz],  # −y
        [x0, y1, z0, 0, 0, dz, dx, 0, 0],  # +y
        [x0, y0, z0, 0, dy, 0, dx, 0, 0],  # −z
        [x0, y0, z1, dx, 0, 0, 0, dy, 0],  # +z
    ], dtype=np.float64)
    if rotate is not None:
        r = rotation_matrix(rotate.axis, rotate.angle)
        faces = (faces.reshape(6, 3, 3) @ r.T).reshape(6, 9)
    faces[:, 0:3] += np.asarray(translate, dtype=np.float64)
    return faces


def _resolve_auto(scene, name: str, m):
    """The material ``auto`` stands for, and the choice with its reason."""
    choice = auto_choice(scene, name)
    if choice.method == "dielectric":
        absorption = tuple(float(t * (1.0 - a))
                           for t, a in zip(m.sigma_t, m.albedo_rgb, strict=True))
        return DielectricMaterial(ior=m.ior, absorption=absorption,
                                  roughness=m.roughness), choice
    if choice.method == "opaque":
        return m.model_copy(update={"method": "diffusion"}), choice
    return m.model_copy(update={"method": choice.method}), choice


# Each family's file packs its row (its slots are named there); the kind tag says which
_PACKERS = {"diffuse": (DIFFUSE, pack_diffuse), "phong": (PHONG, pack_phong),
            "mirror": (MIRROR, pack_mirror), "dielectric": (DIELECTRIC, pack_dielectric),
            "conductor": (CONDUCTOR, pack_conductor)}
_METHODS = {"volumetric": (TRANSLUCENT, pack_translucent),
            "single_scatter": (SINGLE_SCATTER, pack_single_scatter),
            "diffuse_entry": (DIFFUSE_ENTRY, pack_diffuse_entry),
            "backlight": (BACKLIGHT, pack_backlight),
            "diffusion": (DIFFUSION, pack_diffusion)}


def _material_row(name: str, m) -> tuple[int, np.ndarray]:
    """A material's kind tag and parameter row (a translucent one's by its method)."""
    if m.type == "translucent":
        if m.method not in _METHODS:
            raise CompileError(
                f"materials.{name}: the translucent method {m.method!r} is not implemented in "
                "this version of the renderer"
            )
        kind, pack = _METHODS[m.method]
    else:
        kind, pack = _PACKERS[m.type]
    if kind == CONDUCTOR and m.roughness > 0.0:
        kind = ROUGH_CONDUCTOR
    if kind == DIELECTRIC and m.roughness > 0.0:
        kind = ROUGH_DIELECTRIC
    if kind == TRANSLUCENT and m.roughness > 0.0 and m.ior != 1.0:
        kind = ROUGH_TRANSLUCENT  # (at ior 1 the boundary is null, rough or not)
    if kind == DIFFUSE_ENTRY and m.roughness > 0.0 and m.ior != 1.0:
        kind = ROUGH_DIFFUSE_ENTRY
    if kind == DIFFUSION and m.roughness > 0.0 and m.ior != 1.0:
        kind = ROUGH_DIFFUSION
    p = np.zeros(N_PARAMS)
    pack(p, m)
    return kind, p


@np.errstate(over="ignore")  # light powers of absurd radiances: see _selection_pmf
def compile_scene(scene) -> CompiledScene:
    """Pack a validated ``renderer.scene.Scene`` into arrays and build its BVH."""
    names = list(scene.materials)
    mat_index = {name: i for i, name in enumerate(names)}
    mat_kind = np.zeros(len(names), np.int32)
    mat_param = np.zeros((len(names), N_PARAMS))
    auto = {}
    for i, name in enumerate(names):
        m = scene.materials[name]
        if m.type == "translucent" and m.method == "auto":
            m, auto[name] = _resolve_auto(scene, name, m)
        mat_kind[i], mat_param[i] = _material_row(name, untextured(m))
        if name in auto and auto[name].method == "opaque":
            pack_opaque(mat_param[i], m)
    tex_param, texels, mat_tex = pack_textures([scene.materials[n] for n in names], mat_kind,
                                               mat_param)
    textured = len(tex_param) > 0
    smooth = any(obj.type == "mesh" and obj.normal_array() is not None for obj in scene.objects)

    # Objects → primitives
    kinds, geos, mats, emissions, uvs, normals = [], [], [], [], [], []
    n_triangles = 0
    for obj in scene.objects:
        m = mat_index[obj.material]
        if obj.type == "sphere":
            g = np.zeros((1, 9))
            g[0, 0:3] = obj.center
            g[0, 3] = obj.radius
            k = SPHERE
        elif obj.type == "quad":
            g = np.concatenate([obj.origin, obj.edge1, obj.edge2]).reshape(1, 9)
            k = QUAD
        elif obj.type == "box":
            g = box_quads(obj.min, obj.max, obj.rotate, obj.translate)
            k = QUAD
        else:
            verts, tris = obj.arrays()
            v0 = verts[tris[:, 0]]
            g = np.concatenate([v0, verts[tris[:, 1]] - v0, verts[tris[:, 2]] - v0], axis=1)
            k = TRIANGLE
            n_triangles += len(tris)
            if textured:
                uv = obj.uv_array()
                uvs.append(uv[tris].reshape(-1, 6) if uv is not None
                           else np.tile([0.0, 0.0, 1.0, 0.0, 0.0, 1.0], (len(tris), 1)))
            if smooth:
                vn = obj.normal_array()
                normals.append(vn[tris].reshape(-1, 9) if vn is not None
                               else np.full((len(tris), 9), np.nan))
        if textured and k != TRIANGLE:
            uvs.append(np.zeros((len(g), 6)))
        if smooth and k != TRIANGLE:
            normals.append(np.full((len(g), 9), np.nan))
        kinds.append(np.full(len(g), k, np.int8))
        geos.append(np.asarray(g, dtype=np.float64))
        mats.append(np.full(len(g), m, np.int32))
        e = obj.emission if obj.emission is not None else (0.0, 0.0, 0.0)
        emissions.append(np.tile(np.asarray(e, dtype=np.float64), (len(g), 1)))
    prim_kind = np.concatenate(kinds)
    prim_geo = np.concatenate(geos)
    prim_material = np.concatenate(mats)
    prim_emission = np.concatenate(emissions)
    prim_uv = np.concatenate(uvs) if textured else np.zeros((0, 6))
    prim_normal = np.concatenate(normals) if smooth else np.zeros((0, 9))
    # Drop the per-object pieces now: for a large mesh they are as big as the packed arrays, and
    # the BVH build and the reordering below would otherwise stack on top of them (peak memory)
    kinds = geos = mats = emissions = g = v0 = uvs = normals = None

    # BVH, then primitives in BVH order
    lo, hi = prim_bounds(prim_kind, prim_geo)
    if len(prim_kind) >= 2**31 - MAX_LEAF:
        raise CompileError(f"{len(prim_kind)} primitives: the BVH indexes fewer than 2^31")
    is_flat = 0 < len(prim_kind) <= FLAT_MAX
    if is_flat:
        # Few enough to test all at once: no tree (the empty one finds nothing)
        order = flat_order(prim_kind)
        n_binary = bvh_levels = 0
        bvh_lo = bvh_hi = np.zeros((0, 3, BVH_WIDTH))
        bvh_child = bvh_count = np.zeros((0, BVH_WIDTH), np.int32)
    else:
        node_lo, node_hi, node_offset, node_count, order = build_bvh(lo, hi)
        n_binary = len(node_offset)
        bvh_lo, bvh_hi, bvh_child, bvh_count, bvh_levels = widen_bvh(node_lo, node_hi,
                                                                     node_offset, node_count)
        node_lo = node_hi = node_offset = node_count = None
    prim_kind = prim_kind[order]
    prim_geo = np.ascontiguousarray(prim_geo[order])
    prim_material = prim_material[order]
    prim_emission = prim_emission[order]
    if textured:
        prim_uv = np.ascontiguousarray(prim_uv[order])
    if smooth:
        prim_normal = np.ascontiguousarray(prim_normal[order])
    lo, hi = lo[order], hi[order]
    flat = flat_geometry(prim_kind, prim_geo) if is_flat else np.zeros((FLAT_ROWS, 0))
    prim_scale = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))

    # Scene bounds: the radius that turns a directional light's or the background's radiance
    # into a power for light selection (pbrt-v4's DistantLight::Phi)
    s_lo, s_hi = lo.min(axis=0), hi.max(axis=0)
    radius = 0.5 * float(np.linalg.norm(s_hi - s_lo))

    # Lights: emissive primitives, then point and directional lights, then the background
    light_kind, light_prim, light_data, power = [], [], [], []
    prim_light = np.full(len(prim_kind), -1, np.int64)
    emissive = np.nonzero(prim_emission.max(axis=1) > 0.0)[0]
    if len(emissive):
        g = prim_geo[emissive]
        cross = np.cross(g[:, 3:6], g[:, 6:9])
        area = np.linalg.norm(cross, axis=1)
        area = np.where(prim_kind[emissive] == TRIANGLE, 0.5 * area, area)
        sph = prim_kind[emissive] == SPHERE
        area[sph] = 4.0 * math.pi * g[sph, 3] ** 2
        le = prim_emission[emissive]
        lum = le @ LUMINANCE
        prim_light[emissive] = np.arange(len(emissive))
        light_kind.append(np.full(len(emissive), AREA, np.int32))
        light_prim.append(emissive.astype(np.int64))
        data = np.zeros((len(emissive), 6))
        data[:, 3:6] = le
        light_data.append(data)
        power.append(math.pi * lum * area)
    extra_kind, extra_data, extra_power = [], [], []
    for light in scene.lights:
        row = np.zeros(6)
        if light.type == "point":
            row[0:3] = light.position
            row[3:6] = light.intensity
            extra_kind.append(POINT)
            extra_power.append(4.0 * math.pi * _luminance(light.intensity))
        else:
            direction = np.asarray(light.direction, dtype=np.float64)
            row[0:3] = direction / np.linalg.norm(direction)
            row[3:6] = light.irradiance
            extra_kind.append(DIRECTIONAL)
            extra_power.append(math.pi * radius**2 * _luminance(light.irradiance))
        extra_data.append(row)
    background = np.asarray(scene.background, dtype=np.float64)
    env_light = -1
    if background.max() > 0.0:
        row = np.zeros(6)
        row[3:6] = background
        env_light = len(emissive) + len(extra_kind)
        extra_kind.append(BACKGROUND)
        extra_data.append(row)
        extra_power.append(4.0 * math.pi**2 * radius**2 * _luminance(background))
    env_arrays = no_environment()
    if scene.environment is not None:
        env = scene.environment
        rotation = (np.eye(3) if env.rotate is None
                    else rotation_matrix(env.rotate.axis, env.rotate.angle))
        *env_arrays, integral = build_environment(env.pixels(), env.scale, rotation)
        if integral > 0.0:
            env_light = len(emissive) + len(extra_kind)
            extra_kind.append(ENVIRONMENT)
            extra_data.append(np.zeros(6))
            extra_power.append(math.pi * radius**2 * integral)
    if extra_kind:
        light_kind.append(np.asarray(extra_kind, np.int32))
        light_prim.append(np.full(len(extra_kind), -1, np.int64))
        light_data.append(np.asarray(extra_data))
        power.append(np.asarray(extra_power))
    if light_kind:
        light_kind_a = np.concatenate(light_kind)
        light_prim_a = np.concatenate(light_prim)
        light_data_a = np.concatenate(light_data)
        power_a = np.concatenate(power)
    else:
        light_kind_a = np.zeros(0, np.int32)
        light_prim_a = np.zeros(0, np.int64)
        light_data_a = np.zeros((0, 6))
        power_a = np.zeros(0)
    light_pmf = _selection_pmf(power_a)
    light_cdf = np.cumsum(light_pmf)

    arrays = SceneArrays(
        bvh_lo=bvh_lo, bvh_hi=bvh_hi, bvh_child=bvh_child, bvh_count=bvh_count, flat=flat,
        prim_kind=prim_kind, prim_geo=prim_geo, prim_scale=prim_scale,
        prim_material=prim_material, prim_light=prim_light,
        mat_kind=mat_kind, mat_param=mat_param,
        light_kind=light_kind_a, light_prim=light_prim_a, light_data=light_data_a,
        light_cdf=light_cdf, light_pmf=light_pmf, env_light=np.array([env_light], np.int64),
        env_image=env_arrays[0], env_marginal=env_arrays[1], env_conditional=env_arrays[2],
        env_rotation=env_arrays[3],
        camera=camera_array(scene.camera, scene.film.width, scene.film.height),
        background=background,
        null_media=np.array([bool(np.any(
            ((mat_kind == TRANSLUCENT) & (mat_param[:, IOR] == 1.0)) | (mat_kind == SINGLE_SCATTER)
        ))]),
        sampler=np.array([1 if scene.render.sampler == "sobol" else 0], np.int64),
        prim_uv=prim_uv, mat_tex=mat_tex, tex_param=tex_param, texels=texels,
        prim_normal=prim_normal,
        prim_alone=spheres_alone(prim_kind, prim_geo, lo, hi,
                                 np.isin(mat_kind[prim_material], MEDIUM_KINDS)),
    )
    return CompiledScene(
        arrays=arrays,
        width=scene.film.width,
        height=scene.film.height,
        spp=scene.render.spp,
        max_depth=scene.render.max_depth,
        seed=scene.render.seed,
        target_error=scene.render.target_error,
        expected_bias=(frame_bias(scene, auto) if scene.render.target_error is not None
                       else 0.0),
        stack_size=stack_size(int(bvh_levels)),
        info={
            "primitives": int(len(prim_kind)),
            "triangles": int(n_triangles),
            "bvh_nodes": int(len(bvh_child)),
            "bvh_binary_nodes": int(n_binary),
            "flat": bool(flat.shape[1] > 0),
            "lights": int(len(light_kind_a)),
            # per material with method auto: {"method", "reason", "expected_error"}
            "auto": {name: vars(choice) for name, choice in auto.items()},
        },
    )


def _selection_pmf(power: np.ndarray) -> np.ndarray:
    """Light selection probabilities in proportion to power, safe for any finite input.

    The power of an absurd but valid light (radiance 1e300 times an area) overflows to inf; it is
    clamped to the largest float and the powers are scaled by their maximum before summing, so the
    probabilities stay finite. Without any positive power, lights are chosen uniformly.
    """
    if len(power) == 0:
        return np.zeros(0)
    p = np.maximum(np.nan_to_num(power, nan=0.0, posinf=np.finfo(np.float64).max), 0.0)
    if p.max() <= 0.0:
        return np.full(len(p), 1.0 / len(p))
    w = p / p.max()
    return w / w.sum()
