"""Mitsuba 3 bridge: render a Lucent scene with the outside reference renderer.

Mitsuba 3 is an optional extra (``pip install 'lucent-farm[mitsuba]'``), never a runtime dependency:
``mitsuba`` is imported lazily inside the functions below. The bridge exists so that tests and
benchmarks can compare Lucent's images with Mitsuba's **pixel by pixel**, so every mapping below is
meant to be exact (same geometry, same radiometry, same pixel footprint); only the noise differs.

API
---
- :func:`to_mitsuba_dict` — a Lucent scene (the JSON dict of ``SCENE_FORMAT.md``) → a Mitsuba 3
  scene dict for ``mi.load_dict``.
- :func:`render_mitsuba` — render it and return a float32 ``H×W×3`` linear-RGB image.
- :func:`default_variant` — ``"llvm_ad_rgb"`` when Dr.Jit can load libLLVM, else ``"scalar_rgb"``.

Mapping (Lucent → Mitsuba 3)
----------------------------
.. list-table::

 * - camera {position, look_at, up=(0,1,0), fov=39}
   - ``perspective``, ``fov_axis="y"``, ``fov``; ``to_world`` columns (left, up', forward, position)
     with left = −right = normalize(cross(up, forward)). Mitsuba's sample→camera transform maps
     camera-space +x to image *left* (it scales x by −0.5), so this is Mitsuba's own ``look_at``
     and the image is **not** mirrored: image x grows along right = cross(forward, up), row 0 is the
     top, as in Lucent (checked by ``tests/reference/test_mitsuba_bridge.py``).
 * - film {width, height}
   - ``hdrfilm``, ``rfilter="box"`` (radius 0.5: uniform jitter in the pixel square),
     ``pixel_format="rgb"``, ``component_format="float32"``.
 * - render {spp=64, seed=0}
   - ``independent`` sampler (``ldsampler`` for ``render.sampler: sobol``), ``sample_count=spp``,
     ``seed``.
 * - render.max_depth (=-1)
   - Lucent counts scattering events (0 = emitters seen directly, 1 = direct lighting); Mitsuba
     counts path segments (1 = emitters only, 2 = direct). Mitsuba ``max_depth`` = Lucent + 1;
     −1 (unlimited) stays −1. ``rr_depth`` stays at Mitsuba's default (5): Russian roulette is
     unbiased, so it changes the noise, not the expected image.
 * - integrator
   - ``path``; ``volpath`` when any medium is needed (an absorbing dielectric or a volumetric
     translucent). Volpath does not count index-matched (``null``) crossings as depth, and Lucent
     does not count them as scattering events either; medium scattering counts in both.
 * - diffuse {albedo=0.5}
   - ``twosided`` ( ``diffuse`` reflectance ).
 * - mirror {reflectance=1}
   - ``twosided`` ( ``conductor``, ``material="none"`` (Fresnel ≡ 1), ``specular_reflectance`` ).
 * - dielectric {ior=1.5, absorption=0}
   - ``dielectric`` ``int_ior=ior``, ``ext_ior=1``; absorption > 0 adds an interior
     ``homogeneous`` medium, ``sigma_t=absorption``, ``albedo=0`` (pure Beer–Lambert).
 * - translucent, method "volumetric"
   - ``dielectric`` (ior ≠ 1) or ``null`` (ior = 1) boundary; interior ``homogeneous`` medium with
     ``sigma_t`` and ``albedo`` per channel from any form of the coefficients (density, grey or
     RGB; sigma_s and sigma_a; a preset: ``TranslucentMaterial.sigma_t``, ``albedo_rgb``), a
     ``constvolume`` RGB when chromatic, phase ``hg`` g (``isotropic`` when g = 0). Mitsuba's ``hg``
     with g > 0 scatters forward, as Lucent's does. Other methods: ``NotImplementedError``.
 * - phong
   - ``NotImplementedError`` — Mitsuba 3 has no Phong plugin.
 * - sphere {center, radius}
   - ``sphere``; with a textured material, ``to_world`` = translate(center)·R·radius with R
     taking Mitsuba's local (x, y, z) to (d.x, d.y, d.z) = (y, −z, −x), so that Mitsuba's
     u = atan2(y, x)/2π, v = acos(z)/π are the scene format's u = atan2(d.x, −d.z)/2π,
     v = 1 − acos(d.y)/π.
 * - quad {origin, edge1, edge2}
   - ``rectangle`` ([−1,1]² in local xy, normal +z) with ``to_world`` columns (edge1/2, edge2/2,
     n = normalize(cross(edge1, edge2))) and translation origin + edge1/2 + edge2/2. The shading
     normal of the rectangle is then ∝ cross(edge1, edge2) (inverse transpose of that matrix), so
     its one-sided ``area`` emitter lights the same side as Lucent's quad.
 * - box {min, max, rotate, translate}
   - six ``rectangle`` with outward normals; corners rotated about the world origin (Rodrigues,
     right-handed, degrees), then translated.
 * - mesh {vertices, triangles, uvs, normals} / {path} / {asset}, scale, rotate, translate
   - ``mi.Mesh`` filled through ``mi.traverse``: ``vertex_texcoords`` from ``uvs``,
     ``vertex_normals`` from ``normals`` (placed by the inverse transpose); without normals, flat
     face normals cross(v1 − v0, v2 − v0), as Lucent. A file (``path`` relative to ``base_dir``,
     the scene file's folder; an ``asset`` from the local asset cache) is read by Lucent's reader
     (``meshio.parse_mesh``: the same vertices, seams split the same way) and given inline. A
     medium lies behind the faces in both renderers, so a hollow mesh whose inner sheet faces the
     cavity is a shell (``examples/translucent_shell.json``). Placement: the vertices are scaled,
     rotated and translated here (M·x + t).
 * - colour parameters: RGB / bitmap / checkerboard
   - ``rgb``; ``bitmap`` with the texels Lucent decodes (linear float, ``raw``), ``filter_type:
     bilinear``, ``wrap_mode: repeat`` and ``to_uv`` (u, v) ↦ (u·su + ou, 1 − (v·sv + ov))
     (Mitsuba reads v = 0 at the image's top row, Lucent at its bottom); ``checkerboard`` with
     ``to_uv`` scaled by (su/2, sv/2) (Mitsuba's has two squares a unit).
 * - object emission
   - ``area`` emitter, ``radiance`` rgb. Mitsuba's area emitter is one-sided (front = normal side)
     like Lucent's: quads emit on their normal side, spheres/boxes/meshes outward.
 * - lights: point / directional / background
   - ``point`` (position, intensity), ``directional`` (direction = the way light travels,
     irradiance), ``constant`` (radiance) when the background is non-zero.
 * - environment {image, scale, rotate}
   - ``envmap`` with the image Lucent reads (``bitmap``: the same float pixels, whatever the
     file's format), ``scale``, and ``to_world`` = the rotation (Mitsuba looks a world direction
     up at to_world⁻¹·d, as Lucent does). The image is a path relative to ``base_dir`` or an
     asset of the local asset folder.

RGB values above 1 (media ``sigma_t``) are wrapped in a ``constvolume`` because Mitsuba's plain
``rgb`` texture rejects reflectance-like values outside [0, 1]; emitter ``rgb`` is unbounded.

Mitsuba's ``Mesh`` objects belong to one variant, so :func:`to_mitsuba_dict` selects the variant
before it builds them; load the dict under that same variant.

Example::

    import json
    from renderer.mitsuba_bridge import render_mitsuba
    img = render_mitsuba(json.load(open("examples/cornell_box.json")), spp=256, seed=3)
"""

from __future__ import annotations

import copy
import ctypes.util
import glob
import math
import os
import re
from typing import Any

import numpy as np

from renderer.scene.schema import TranslucentMaterial

__all__ = ["default_variant", "render_mitsuba", "to_mitsuba_dict"]

_INSTALL_HINT = "pip install 'lucent-farm[mitsuba]'"

# Debian's LLVM 19 (``apt-get install libllvm19``), which Dr.Jit's LLVM backend compiles with.
_LIBLLVM_DEFAULT = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
# The oldest LLVM the bridge hands to Dr.Jit (see _find_libllvm).
_MIN_LLVM = 16

# JIT variants trace one wavefront of width·height·spp lanes; above this many lanes a render is
# split into passes with derived seeds so that memory stays bounded (16384 spp at 64×48 would be
# 50 M lanes, several GB of loop state).
_MAX_LANES_PER_PASS = 1 << 23


# --------------------------------------------------------------------------------------------------
# Variant selection and lazy import
# --------------------------------------------------------------------------------------------------


def _llvm_major(path: str) -> int | None:
    """The LLVM major version in a library's file name (``libLLVM-19.so``, ``libLLVM.so.19.1``)."""
    m = re.search(r"libLLVM(?:-(\d+)|\.so\.(\d+))", os.path.basename(path))
    if m is None:
        return None
    return int(m.group(1) or m.group(2))


def _find_libllvm() -> str | None:
    """Path of a libLLVM shared library for Dr.Jit, setting DRJIT_LIBLLVM_PATH when we pick one.

    Only LLVM >= ``_MIN_LLVM`` is taken: Dr.Jit 1.x with Debian 12's LLVM 15 aborts the process in
    instruction selection on the first Mitsuba render (seen here), so an old library found on the
    system means "no LLVM" (``scalar_rgb``), not a crash. The newest version found wins.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env if os.path.isfile(env) else None
    candidates = [_LIBLLVM_DEFAULT]
    found = ctypes.util.find_library("LLVM")
    if found:
        candidates.append(found if os.path.isabs(found) else f"/usr/lib/x86_64-linux-gnu/{found}")
    for libdir in ("/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib"):
        candidates += glob.glob(os.path.join(libdir, "libLLVM*.so*"))
    majors = {p: _llvm_major(p) or 0 for p in candidates if os.path.isfile(p)}
    usable = [p for p, major in majors.items() if major >= _MIN_LLVM]
    if not usable:
        return None
    path = max(usable, key=majors.__getitem__)
    # Must be set before Dr.Jit initialises its LLVM backend.
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def _import_mitsuba() -> Any:
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"Mitsuba 3 is needed for the reference renders: {_INSTALL_HINT}"
        ) from exc
    return mi


def default_variant() -> str:
    """``"llvm_ad_rgb"`` when Dr.Jit can load libLLVM, else ``"scalar_rgb"``."""
    if _find_libllvm() is None:
        return "scalar_rgb"
    mi = _import_mitsuba()
    import drjit as dr

    if "llvm_ad_rgb" in mi.variants() and dr.has_backend(dr.JitBackend.LLVM):
        return "llvm_ad_rgb"
    return "scalar_rgb"


def _use_variant(variant: str | None) -> Any:
    """Import Mitsuba and select ``variant`` (None: the current one, or the default if none)."""
    mi = _import_mitsuba()
    if variant is None:
        variant = mi.variant() or default_variant()
    elif variant.startswith("llvm"):
        _find_libllvm()
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


# --------------------------------------------------------------------------------------------------
# Small geometry helpers (plain NumPy)
# --------------------------------------------------------------------------------------------------


def _vec3(value: Any, path: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,):
        raise ValueError(f"{path}: expected 3 numbers, got {value!r}")
    return v


def _normalize(v: np.ndarray, path: str) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n == 0.0 or not math.isfinite(n):
        raise ValueError(f"{path}: degenerate (zero-length) vector")
    return v / n


def _rotation_matrix(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rodrigues' formula, R = I + sin θ K + (1 − cos θ) K², right-handed about ``axis``."""
    kx, ky, kz = _normalize(axis, "rotate.axis")
    k_cross = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    theta = math.radians(angle_deg)
    return np.eye(3) + math.sin(theta) * k_cross + (1.0 - math.cos(theta)) * (k_cross @ k_cross)


def _rectangle_matrix(origin: np.ndarray, edge1: np.ndarray, edge2: np.ndarray) -> np.ndarray:
    """Affine map from Mitsuba's [-1,1]² rectangle (normal +z) onto origin + s·edge1 + t·edge2."""
    normal = _normalize(np.cross(edge1, edge2), "quad: edge1 × edge2")
    m = np.eye(4)
    m[:3, 0] = edge1 / 2.0
    m[:3, 1] = edge2 / 2.0
    m[:3, 2] = normal
    m[:3, 3] = origin + edge1 / 2.0 + edge2 / 2.0
    return m


def _camera_matrix(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera-to-world matrix, identical to Mitsuba's ``Transform4f.look_at``.

    Columns (left, up', forward, position): Mitsuba's perspective camera looks down local +z and
    its film x grows towards local −x, so image x grows along −left = cross(forward, up) = Lucent's
    right. No mirroring is needed.
    """
    forward = _normalize(target - position, "camera.look_at - camera.position")
    left = _normalize(np.cross(up, forward), "camera.up × forward (up parallel to view?)")
    true_up = np.cross(forward, left)
    m = np.eye(4)
    m[:3, 0] = left
    m[:3, 1] = true_up
    m[:3, 2] = forward
    m[:3, 3] = position
    return m


def _box_faces(obj: dict, path: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The six faces of a box as (origin, edge1, edge2) with cross(edge1, edge2) pointing out."""
    lo = _vec3(obj["min"], f"{path}.min")
    hi = _vec3(obj["max"], f"{path}.max")
    if np.any(hi <= lo):
        raise ValueError(f"{path}: max must be > min on every axis")
    size = hi - lo
    rotate = obj.get("rotate")
    rot = (
        _rotation_matrix(_vec3(rotate["axis"], f"{path}.rotate.axis"), float(rotate["angle"]))
        if rotate is not None
        else np.eye(3)
    )
    translate = _vec3(obj.get("translate", [0.0, 0.0, 0.0]), f"{path}.translate")
    basis = np.eye(3)
    faces = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3  # e_b × e_c = e_a
        eb, ec = size[b] * basis[b], size[c] * basis[c]
        # +a face: edges (eb, ec) → normal +e_a.  −a face: swapped → normal −e_a.
        for corner, e1, e2 in ((hi[a] * basis[a], eb, ec), (lo[a] * basis[a], ec, eb)):
            origin = corner + lo[b] * basis[b] + lo[c] * basis[c]
            faces.append((rot @ origin + translate, rot @ e1, rot @ e2))
    return faces


# --------------------------------------------------------------------------------------------------
# Scene dict pieces
# --------------------------------------------------------------------------------------------------


def _rgb(value: Any, path: str) -> dict:
    return {"type": "rgb", "value": [float(x) for x in _vec3(value, path)]}


def _unbounded_rgb(value: Any, path: str) -> dict:
    """An RGB medium coefficient that may exceed 1 (``rgb`` alone is checked against [0, 1])."""
    return {"type": "constvolume", "value": _rgb(value, path)}


def _file_bytes(ref: Any, where: str, kinds: tuple[str, ...],
                base_dir: str | os.PathLike | None) -> tuple[bytes, str, str]:
    """(bytes, kind, label) of a file reference (a path relative to ``base_dir``, or an asset in
    the local asset cache), as Lucent's loader reads it."""
    from pathlib import Path

    from renderer.scene.files import FileSource, local_assets
    from renderer.scene.schema import AssetRef

    if isinstance(ref, dict):
        ref = AssetRef(**ref)
    source = FileSource(allow_paths=True, base_dir=None if base_dir is None else Path(base_dir),
                        assets=local_assets())
    read = source.read(ref, where, kinds)
    if isinstance(read, list):
        raise ValueError("; ".join(f"{path}: {message}" for path, message in read))
    return read


def _colour(mi: Any, value: Any, path: str, base_dir: str | os.PathLike | None) -> dict:
    """A colour parameter: ``rgb``, or the texture Mitsuba 3 reads the same way. Mitsuba looks
    a bitmap up with v = 0 at the image's top row, Lucent (and OBJ) at its bottom row: ``to_uv``
    maps (u, v) to (u·su + ou, 1 − (v·sv + ov)). Mitsuba's checkerboard has two squares a unit
    (color0 where both fractional parts are below ½ or both above): ``to_uv`` scales by s/2."""
    if not isinstance(value, dict):
        return _rgb(value, path)
    kind = value.get("type")
    if kind == "checkerboard":
        su, sv = value.get("scale", [2.0, 2.0])
        return {"type": "checkerboard",
                "color0": _rgb(value.get("color0", [0.4, 0.4, 0.4]), f"{path}.color0"),
                "color1": _rgb(value.get("color1", [0.2, 0.2, 0.2]), f"{path}.color1"),
                "to_uv": mi.ScalarTransform4f(np.diag([su / 2.0, sv / 2.0, 1.0, 1.0]))}
    if kind == "bitmap":
        from renderer.film.image_io import decode_texture

        data, file_kind, label = _file_bytes(value.get("image"), f"{path}.image",
                                             (".png", ".exr", ".pfm"), base_dir)
        pixels = decode_texture(data, file_kind, srgb=value.get("srgb"), name=label)
        su, sv = value.get("scale", [1.0, 1.0])
        ou, ov = value.get("offset", [0.0, 0.0])
        # (u, v) ↦ the 4 × 4's x and y of the point (u, v, 0) (translation in the last column)
        to_uv = np.eye(4)
        to_uv[0, 0], to_uv[0, 3] = su, ou
        to_uv[1, 1], to_uv[1, 3] = -sv, 1.0 - ov
        return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(pixels, np.float32)),
                "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat",
                "to_uv": mi.ScalarTransform4f(to_uv)}
    raise ValueError(f"{path}.type: unknown texture type {kind!r}")


def _material(materials: dict, name: str, path: str, mi: Any = None,
              base_dir: str | os.PathLike | None = None) -> tuple[dict, dict | None]:
    """Mitsuba (bsdf, interior medium or None) for the Lucent material ``name`` (``mi`` for
    its textures)."""

    def _rgb(value: Any, where: str) -> dict:  # a colour parameter, which may be a texture
        return _colour(mi, value, where, base_dir)

    if name not in materials:
        raise ValueError(f"{path}.material: unknown material {name!r}")
    mat = materials[name]
    mpath = f"materials.{name}"
    kind = mat.get("type")
    if kind == "diffuse":
        albedo = mat.get("albedo", [0.5, 0.5, 0.5])
        inner = {"type": "diffuse", "reflectance": _rgb(albedo, f"{mpath}.albedo")}
        return {"type": "twosided", "bsdf": inner}, None
    if kind == "mirror":
        reflectance = mat.get("reflectance", [1.0, 1.0, 1.0])
        alpha = float(mat.get("roughness", 0.0))
        rough = {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                 "sample_visible": True} if alpha > 0.0 else {"type": "conductor"}
        inner = rough | {
            "material": "none",
            "specular_reflectance": _rgb(reflectance, f"{mpath}.reflectance"),
        }
        return {"type": "twosided", "bsdf": inner}, None
    if kind == "conductor":
        from renderer.materials.conductor import CONDUCTOR_PRESETS

        if mat.get("preset") is not None:
            eta, k = CONDUCTOR_PRESETS[mat["preset"]]
        else:
            eta, k = mat["eta"], mat["k"]
        alpha = float(mat.get("roughness", 0.0))
        rough = {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                 "sample_visible": True} if alpha > 0.0 else {"type": "conductor"}
        inner = rough | {
            # Mitsuba takes eta and k as unbounded spectra (values above 1 are fine)
            "eta": _rgb(eta, f"{mpath}.eta"),
            "k": _rgb(k, f"{mpath}.k"),
            "specular_reflectance": _rgb(mat.get("specular", [1.0, 1.0, 1.0]),
                                         f"{mpath}.specular"),
        }
        return {"type": "twosided", "bsdf": inner}, None
    if kind == "dielectric":
        ior = float(mat.get("ior", 1.5))
        absorption = _vec3(mat.get("absorption", [0.0, 0.0, 0.0]), f"{mpath}.absorption")
        alpha = float(mat.get("roughness", 0.0))
        bsdf = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}
        if alpha > 0.0:
            bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": alpha,
                    "sample_visible": True, "int_ior": ior, "ext_ior": 1.0}
        medium = None
        if np.any(absorption > 0.0):
            # Beer–Lambert only: every extinction event absorbs (albedo 0).
            medium = {
                "type": "homogeneous",
                "sigma_t": _unbounded_rgb(absorption, f"{mpath}.absorption"),
                "albedo": 0.0,
            }
        return bsdf, medium
    if kind == "phong":
        raise NotImplementedError("phong has no Mitsuba 3 counterpart")
    if kind == "translucent":
        method = mat.get("method")
        if method is None:
            raise ValueError(f"{mpath}.method: required by the Mitsuba bridge")
        if method != "volumetric":
            raise NotImplementedError(
                f"{mpath}: translucent method {method!r} has no Mitsuba 3 counterpart "
                "(only 'volumetric' does)"
            )
        ior = float(mat["ior"])
        g = float(mat.get("g", 0.0))
        phase = {"type": "isotropic"} if g == 0.0 else {"type": "hg", "g": g}
        # Every form of the coefficients (albedo and density, grey or per channel; sigma_s and
        # sigma_a; a preset) as the renderer reads them: (albedo, σt) per channel
        m = TranslucentMaterial.model_validate(mat)
        sigma_t: Any = (_unbounded_rgb(m.sigma_t, f"{mpath}.density") if m.chromatic
                        else m.sigma_t[0])
        medium = {
            "type": "homogeneous",
            "sigma_t": sigma_t,
            "albedo": _rgb(m.albedo_rgb, f"{mpath}.albedo"),
            "phase": phase,
        }
        alpha = float(mat.get("roughness", 0.0))
        if ior == 1.0:
            bsdf: dict = {"type": "null"}
        elif alpha > 0.0:
            bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": alpha,
                    "sample_visible": True, "int_ior": ior, "ext_ior": 1.0}
        else:
            bsdf = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}
        return bsdf, medium
    raise ValueError(f"{mpath}.type: unknown material type {kind!r}")


def _area(emission: Any, path: str) -> dict | None:
    if emission is None:
        return None
    radiance = _vec3(emission, path)
    if not np.any(radiance != 0.0):
        return None
    return {"type": "area", "radiance": _rgb(radiance, path)}


def _mesh_placement(obj: dict, path: str) -> tuple[np.ndarray | None, np.ndarray]:
    """A mesh's ``scale`` (a number or per axis), ``rotate``, ``translate`` as x ↦ M·x + t
    (scaled first, then rotated about the origin, then moved); (None, 0) when it has none."""
    if not any(k in obj for k in ("scale", "rotate", "translate")):
        return None, np.zeros(3)
    scale = obj.get("scale", 1.0)
    m = np.diag(np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,)))
    if obj.get("rotate") is not None:
        rotate = obj["rotate"]
        m = _rotation_matrix(_vec3(rotate["axis"], f"{path}.rotate.axis"),
                             float(rotate["angle"])) @ m
    t = _vec3(obj.get("translate", [0.0, 0.0, 0.0]), f"{path}.translate")
    return m, t


def _inline_mesh(
    mi: Any, obj: dict, path: str, key: str, bsdf: dict, medium: dict | None, emitter: dict | None
) -> Any:
    """A ``mi.Mesh`` from inline vertices/triangles: flat face normals, or the mesh's ``normals``
    (placed by the inverse transpose) and its ``uvs``."""
    vertices = np.asarray(obj["vertices"], dtype=np.float64)
    triangles = np.asarray(obj["triangles"], dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ValueError(f"{path}.vertices: expected a non-empty list of [x, y, z]")
    m, t = _mesh_placement(obj, path)
    if m is not None:
        vertices = vertices @ m.T + t
    vertices = vertices.astype(np.float32)
    if triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0:
        raise ValueError(f"{path}.triangles: expected a non-empty list of [i, j, k]")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise ValueError(f"{path}.triangles: vertex index out of range")
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    if medium is not None:
        props["interior"] = mi.load_dict(medium)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    # No vertex normals: Mitsuba then shades with the geometric (face) normal, no smoothing.
    normals = obj.get("normals")
    uvs = obj.get("uvs")
    mesh = mi.Mesh(key, len(vertices), len(triangles), props=props,
                   has_vertex_normals=normals is not None,
                   has_vertex_texcoords=uvs is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = vertices.ravel()
    params["faces"] = triangles.astype(np.uint32).ravel()
    if normals is not None:
        normals = np.asarray(normals, np.float64).reshape(-1, 3)
        if m is not None:
            normals = normals @ np.linalg.inv(m)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        params["vertex_normals"] = normals.astype(np.float32).ravel()
    if uvs is not None:
        params["vertex_texcoords"] = np.asarray(uvs, np.float32).ravel()
    params.update()
    return mesh


def _shapes(mi: Any, scene: dict, base_dir: str | os.PathLike | None) -> tuple[dict, bool]:
    """Mitsuba shapes keyed by id, and whether any medium is present."""
    materials = scene.get("materials", {})
    shapes: dict[str, Any] = {}
    any_medium = False
    for i, obj in enumerate(scene.get("objects", [])):
        path = f"objects[{i}]"
        key = f"object_{i:03d}"
        bsdf, medium = _material(materials, obj.get("material"), path, mi, base_dir)
        any_medium |= medium is not None
        emitter = _area(obj.get("emission"), f"{path}.emission")

        def dress(shape: dict, bsdf=bsdf, medium=medium, emitter=emitter) -> dict:
            shape["bsdf"] = bsdf
            if medium is not None:
                shape["interior"] = medium
            if emitter is not None:
                shape["emitter"] = emitter
            return shape

        kind = obj.get("type")
        textured = any(isinstance(v, dict) for v in materials.get(obj.get("material"), {})
                       .values())
        if kind == "sphere" and not textured:
            shapes[key] = dress(
                {
                    "type": "sphere",
                    "center": [float(x) for x in _vec3(obj["center"], f"{path}.center")],
                    "radius": float(obj["radius"]),
                }
            )
        elif kind == "sphere":
            # Mitsuba's sphere is parametrized about its local +z, Lucent's about +y with u = 0
            # towards −z: local (x, y, z) = (−d.z, d.x, −d.y) gives both the same (u, v)
            world = np.eye(4)
            world[:3, :3] = float(obj["radius"]) * np.array(
                [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
            world[:3, 3] = _vec3(obj["center"], f"{path}.center")
            shapes[key] = dress(
                {
                    "type": "sphere",
                    "to_world": mi.ScalarTransform4f(world),
                }
            )
        elif kind == "quad":
            m = _rectangle_matrix(
                _vec3(obj["origin"], f"{path}.origin"),
                _vec3(obj["edge1"], f"{path}.edge1"),
                _vec3(obj["edge2"], f"{path}.edge2"),
            )
            shapes[key] = dress({"type": "rectangle", "to_world": mi.ScalarTransform4f(m)})
        elif kind == "box":
            for k, (origin, e1, e2) in enumerate(_box_faces(obj, path)):
                m = _rectangle_matrix(origin, e1, e2)
                shapes[f"{key}_face{k}"] = dress(
                    {"type": "rectangle", "to_world": mi.ScalarTransform4f(m)}
                )
        elif kind == "mesh":
            if "path" in obj or "asset" in obj:
                # Read by Lucent's reader (relative to the scene file, as Lucent's loader reads
                # it) and given to Mitsuba inline: the same vertices, seams split the same way,
                # normals and texture coordinates where the file has them, else none (Mitsuba
                # would smooth a file without normals)
                from renderer.geometry.meshio import parse_mesh

                field = f"{path}.path" if "path" in obj else f"{path}.asset"
                ref = obj["path"] if "path" in obj else {"asset": obj["asset"]}
                data, file_kind, label = _file_bytes(ref, field, (".obj", ".ply"), base_dir)
                vertices, triangles, uvs, normals = parse_mesh(data, file_kind, name=label)
                inline = {k: v for k, v in obj.items() if k not in ("path", "asset")}
                inline.update(vertices=vertices, triangles=triangles)
                if uvs is not None:
                    inline["uvs"] = uvs
                if normals is not None:
                    inline["normals"] = normals
                shapes[key] = _inline_mesh(mi, inline, path, key, bsdf, medium, emitter)
            else:
                shapes[key] = _inline_mesh(mi, obj, path, key, bsdf, medium, emitter)
        else:
            raise ValueError(f"{path}.type: unknown object type {kind!r}")
    return shapes, any_medium


def _lights(scene: dict) -> dict:
    lights: dict[str, dict] = {}
    for i, light in enumerate(scene.get("lights", [])):
        path = f"lights[{i}]"
        kind = light.get("type")
        if kind == "point":
            lights[f"light_{i:03d}"] = {
                "type": "point",
                "position": [float(x) for x in _vec3(light["position"], f"{path}.position")],
                "intensity": _rgb(light["intensity"], f"{path}.intensity"),
            }
        elif kind == "directional":
            # Both formats give the direction in which the light travels.
            direction = _normalize(_vec3(light["direction"], f"{path}.direction"), path)
            lights[f"light_{i:03d}"] = {
                "type": "directional",
                "direction": [float(x) for x in direction],
                "irradiance": _rgb(light["irradiance"], f"{path}.irradiance"),
            }
        else:
            raise ValueError(f"{path}.type: unknown light type {kind!r}")
    background = _vec3(scene.get("background", [0.0, 0.0, 0.0]), "background")
    if np.any(background != 0.0):
        lights["background"] = {"type": "constant", "radiance": _rgb(background, "background")}
    return lights


def _environment(mi: Any, scene: dict, base_dir: str | os.PathLike | None) -> dict:
    """The ``envmap`` emitter of the scene's ``environment`` (empty without one)."""
    env = scene.get("environment")
    if env is None:
        return {}
    from renderer.film.image_io import decode_hdr_image

    data, kind, label = _file_bytes(env.get("image"), "environment.image",
                                    (".exr", ".pfm", ".hdr"), base_dir)
    pixels = decode_hdr_image(data, kind, name=label)
    emitter: dict[str, Any] = {"type": "envmap", "bitmap": mi.Bitmap(pixels),
                               "scale": float(env.get("scale", 1.0))}
    rotate = env.get("rotate")
    if rotate is not None:
        r = np.eye(4)
        r[:3, :3] = _rotation_matrix(_vec3(rotate["axis"], "environment.rotate.axis"),
                                     float(rotate["angle"]))
        emitter["to_world"] = mi.ScalarTransform4f(r)
    return {"environment": emitter}


def to_mitsuba_dict(
    scene: dict, *, variant: str | None = None, base_dir: str | os.PathLike | None = None
) -> dict:
    """Convert a Lucent scene dict into a Mitsuba 3 scene dict (for ``mi.load_dict``).

    Applies the documented defaults of the scene format. ``variant`` selects the Mitsuba variant
    first (None: keep the current one, or :func:`default_variant` if none is set); inline meshes are
    Mitsuba objects of that variant. A mesh ``path`` is read relative to ``base_dir`` (the scene
    file's folder, as ``load_scene_file`` does; None: the working directory).

    Raises ``NotImplementedError`` for materials Mitsuba 3 cannot express (phong, translucent
    methods other than ``volumetric``) and ``ValueError`` naming the JSON path of a bad field.
    """
    mi = _use_variant(variant)
    camera = scene["camera"]
    film = scene["film"]
    render = scene.get("render", {})

    # Camera and film
    cam_to_world = _camera_matrix(
        _vec3(camera["position"], "camera.position"),
        _vec3(camera["look_at"], "camera.look_at"),
        _vec3(camera.get("up", [0.0, 1.0, 0.0]), "camera.up"),
    )
    sensor = {
        "type": "perspective",
        "fov_axis": "y",
        "fov": float(camera.get("fov", 39.0)),
        "to_world": mi.ScalarTransform4f(cam_to_world),
        "sampler": {
            # Lucent's sobol sampler ↔ Mitsuba's (0,2)-sequence sampler with padding
            "type": "ldsampler" if render.get("sampler") == "sobol" else "independent",
            "sample_count": int(render.get("spp", 64)),
            "seed": int(render.get("seed", 0)),
        },
        "film": {
            "type": "hdrfilm",
            "width": int(film["width"]),
            "height": int(film["height"]),
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
    }

    shapes, any_medium = _shapes(mi, scene, base_dir)

    # Integrator: Lucent counts scattering events, Mitsuba path segments.
    max_depth = int(render.get("max_depth", -1))
    if max_depth < -1:
        raise ValueError("render.max_depth: must be >= -1")
    integrator = {
        "type": "volpath" if any_medium else "path",
        "max_depth": -1 if max_depth == -1 else max_depth + 1,
    }

    out: dict[str, Any] = {"type": "scene", "integrator": integrator, "sensor": sensor}
    out.update(shapes)
    out.update(_lights(scene))
    out.update(_environment(mi, scene, base_dir))
    return out


def _pass_seeds(seed: int, n_passes: int) -> list[int]:
    """Seeds of the passes of one render: the seed itself for one pass, else hashed (seed, k)."""
    if n_passes == 1:
        return [seed]
    states = [np.random.SeedSequence([seed, k]).generate_state(1)[0] for k in range(n_passes)]
    return [int(s) for s in states]


def render_mitsuba(
    scene: dict,
    spp: int | None = None,
    seed: int = 0,
    variant: str | None = None,
    base_dir: str | os.PathLike | None = None,
) -> np.ndarray:
    """Render a Lucent scene with Mitsuba 3; returns linear RGB, float32, shape (H, W, 3).

    ``spp`` defaults to the scene's ``render.spp`` (64); ``variant`` to :func:`default_variant`.
    With a JIT variant, more than ``_MAX_LANES_PER_PASS`` samples are split into equal passes with
    seeds derived from ``seed`` and averaged (weighted by their spp), which is the same estimator.
    ``base_dir``: where relative mesh paths are read from (see :func:`to_mitsuba_dict`).
    """
    mi = _use_variant(variant or default_variant())
    if spp is None:
        spp = int(scene.get("render", {}).get("spp", 64))
    if spp < 1:
        raise ValueError("spp: must be >= 1")
    mi_scene = mi.load_dict(to_mitsuba_dict(scene, variant=mi.variant(), base_dir=base_dir))

    pixels = int(scene["film"]["width"]) * int(scene["film"]["height"])
    n_passes = 1
    if not mi.variant().startswith("scalar"):
        n_passes = max(1, math.ceil(spp * pixels / _MAX_LANES_PER_PASS))
    spp_per_pass = [spp // n_passes + (k < spp % n_passes) for k in range(n_passes)]

    total = None
    for pass_spp, pass_seed in zip(spp_per_pass, _pass_seeds(seed, n_passes), strict=True):
        img = np.array(mi.render(mi_scene, spp=pass_spp, seed=pass_seed), dtype=np.float64)
        total = img * pass_spp if total is None else total + img * pass_spp
    return (total / spp).astype(np.float32)


def grey_at_channel(scene: dict, k: int) -> dict:
    """The scene with every translucent medium made grey at channel k's σt (its albedo and
    σt per channel as the renderer reads any form of its coefficients)."""
    scene = copy.deepcopy(scene)
    for name, mat in scene["materials"].items():
        if mat.get("type") != "translucent":
            continue
        m = TranslucentMaterial.model_validate(mat)
        keep = {key: v for key, v in mat.items() if key not in
                ("albedo", "density", "sigma_s", "sigma_a", "preset", "preset_scale")}
        scene["materials"][name] = keep | {"albedo": list(m.albedo_rgb),
                                           "density": m.sigma_t[k]}
    return scene


def is_chromatic(scene: dict) -> bool:
    """Whether a translucent medium of the scene has σt that differs between channels."""
    return any(TranslucentMaterial.model_validate(m).chromatic
               for m in scene["materials"].values() if m.get("type") == "translucent")


def render_mitsuba_split(scene: dict, spp: int | None = None, seed: int = 0,
                         variant: str | None = None,
                         base_dir: str | os.PathLike | None = None) -> np.ndarray:
    """``render_mitsuba`` split by channel: channel k from a render of ``grey_at_channel(scene,
    k)``. RGB light transport is independent per channel, so this is the scene's image; for a
    chromatic medium it is the reference, where Mitsuba's RGB ``volpath`` (flights from one
    channel, no MIS over the channels) stays covered in coloured fireflies at thousands of spp."""
    img = None
    for k in range(3):
        part = render_mitsuba(grey_at_channel(scene, k), spp, seed, variant, base_dir)
        img = part.copy() if img is None else img
        img[..., k] = part[..., k]
    assert img is not None
    return img

