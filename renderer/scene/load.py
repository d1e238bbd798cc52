"""Loading and validating scenes: JSON -> ``Scene``, or a ``SceneError`` naming every fault.

Validation runs in three rounds, each only if the previous one passed:

1. size guard: counts of objects, lights, materials and inline triangles against ``Limits``, on
   the raw document, so that an oversized scene is refused before it is parsed;
2. structure: the pydantic models (types, ranges, unknown fields, per-object checks);
3. semantics, all collected before raising: material references, the film and render limits,
   meshes (files read, index range, degenerate triangles, closedness) and the triangle budget.

Every error carries the JSON path of the bad value (``objects[3].radius``) and a short message.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from renderer.scene.files import AssetReader, FileSource, local_assets
from renderer.scene.limits import Limits
from renderer.scene.schema import (
    COLOUR_PARAMS,
    LIGHT_TYPES,
    MATERIAL_TYPES,
    OBJECT_TYPES,
    TEXTURE_TYPES,
    VOLUME_MATERIAL_TYPES,
    AssetRef,
    BitmapTexture,
    Mesh,
    Scene,
    is_texture,
    overflow_message,
)

ROOT = "(root)"
"""Path of errors about the document as a whole."""

FILE = "(file)"
"""Path of errors about a scene file that cannot be read or is not JSON."""

MESH_KINDS = (".obj", ".ply")
"""The mesh files a scene may name."""

ENVIRONMENT_KINDS = (".exr", ".pfm", ".hdr")
"""The images an environment may be."""

TEXTURE_KINDS = (".png", ".exr", ".pfm")
"""The images a bitmap texture may be."""

# How many faulty triangles of one mesh are named before the rest are only counted.
MAX_REPORTED = 5

# A triangle is degenerate if |e1 x e2| <= EPS_DEGENERATE * (product of its two longest edges):
# twice its area is negligible against its size, and its normal would be noise or NaN.
EPS_DEGENERATE = 1e-10

# Triangles per block in the area test: bounds the temporary arrays (about 200 MB at 4M).
_BLOCK = 1 << 20


class SceneError(ValueError):
    """A scene that cannot be rendered, with every problem found: ``errors`` is a list of
    (JSON path, message); ``str()`` gives one ``path: message`` line per error.

    ``SceneError("film.width", "must be >= 1")`` or ``SceneError([(path, message), ...])``.
    """

    def __init__(self, errors: str | Iterable[tuple[str, str]], message: str | None = None):
        if isinstance(errors, str):
            if message is None:
                raise TypeError("SceneError(path, message) needs a message")
            items = [(errors, message)]
        else:
            items = [(str(path), str(msg)) for path, msg in errors]
        # args = (errors,) so that the exception pickles and unpickles as itself.
        super().__init__(items)
        self.errors: list[tuple[str, str]] = items

    def __str__(self) -> str:
        return "\n".join(f"{path}: {message}" for path, message in self.errors)

    def as_dicts(self) -> list[dict[str, str]]:
        """``[{"path": ..., "message": ...}, ...]``, e.g. for an HTTP 422 body."""
        return [{"path": path, "message": message} for path, message in self.errors]


# --- Entry points ---------------------------------------------------------------------------------


def load_scene(
    data: Any,
    *,
    limits: Limits | None = None,
    allow_paths: bool = False,
    base_dir: Path | None = None,
    assets: AssetReader | None = None,
) -> Scene:
    """Validate a scene document (a dict as from ``json.loads``) and return the ``Scene``.

    ``limits``: resource limits, ``Limits()`` (from the environment) if None. ``allow_paths``:
    accept meshes given by a file ``path`` (the CLI only: a server must never read a path that a
    request names); relative paths are resolved against ``base_dir`` (else the working directory).
    Meshes read from files are held as arrays (``Mesh.arrays()``) and their ``path`` is cleared.
    ``assets``: the reader of uploaded assets (``{"asset": "sha256:..."}``, mesh ``asset``); without
    one, a scene that names an asset is refused (``renderer.scene.files``).

    Raises ``SceneError`` listing every problem found.
    """
    if limits is None:
        limits = Limits()
    if not isinstance(data, Mapping):
        raise SceneError(ROOT, "a scene must be a JSON object")

    # Round 1: refuse a scene too large to be worth parsing.
    guard = _size_guard(data, limits)
    if guard:
        raise SceneError(guard)

    # Round 2: structure.
    try:
        scene = Scene.model_validate(data, context={"allow_paths": allow_paths})
    except ValidationError as exc:
        raise SceneError(_convert_validation_error(exc)) from None

    # Round 3: semantics.
    errors: list[tuple[str, str]] = []
    errors += _check_render_limits(scene, limits)
    errors += _check_material_references(scene)
    files = FileSource(allow_paths=allow_paths, base_dir=base_dir, assets=assets)
    total_triangles = 0
    for i, obj in enumerate(scene.objects):
        if isinstance(obj, Mesh):
            errors += _check_mesh(scene, i, obj, files)
            total_triangles += obj.num_triangles
    errors += _check_count("objects", total_triangles, limits, "max_triangles", "triangles")
    if scene.environment is not None:
        errors += _check_environment(scene, files, limits)
    errors += _check_textures(scene, files, limits)
    if not errors:
        errors += _check_auto_textures(scene)
    if errors:
        raise SceneError(errors)
    return scene


def _check_auto_textures(scene) -> list[tuple[str, str]]:
    """A textured albedo with method auto: refused where auto renders the material as a glass,
    which a texture cannot colour (``renderer.materials.auto.texture_refusal``)."""
    from renderer.materials.auto import auto_choice, texture_refusal

    errors = []
    for name, m in scene.materials.items():
        if m.type == "translucent" and m.method == "auto" and is_texture(m.albedo):
            why = texture_refusal(auto_choice(scene, name))
            if why is not None:
                errors.append((f"materials.{name}.albedo", why))
    return errors


def load_scene_file(
    path: str | os.PathLike[str],
    *,
    limits: Limits | None = None,
    assets: AssetReader | None = None,
) -> Scene:
    """Read and validate a scene file (the CLI): file paths are allowed, relative to it; assets
    come from ``assets``, else the local asset folder (``files.local_assets``)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(FILE, f"cannot read {str(path)!r}: {exc.strerror or exc}") from None

    # Python's json accepts NaN and Infinity, which JSON does not: parse them to a marker that
    # no field accepts, so that the error names the field they were in.
    markers: list[NonFiniteJSON] = []

    def parse_constant(token: str) -> NonFiniteJSON:
        markers.append(NonFiniteJSON(token))
        return markers[-1]

    try:
        data = json.loads(raw, parse_constant=parse_constant)
    except json.JSONDecodeError as exc:
        raise SceneError(
            FILE, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except UnicodeDecodeError as exc:
        raise SceneError(FILE, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None

    scene = load_scene(
        data,
        limits=limits,
        allow_paths=True,
        base_dir=path.resolve().parent,
        assets=assets if assets is not None else local_assets(),
    )
    if markers:  # unreachable (every field refuses the marker); kept as a backstop
        raise SceneError(ROOT, f"{markers[0].token} is not valid JSON: numbers must be finite")
    return scene


class NonFiniteJSON:
    """Stands for a ``NaN``/``Infinity``/``-Infinity`` token in a scene file (not valid JSON)."""

    __slots__ = ("token",)

    def __init__(self, token: str):
        self.token = token

    def __repr__(self) -> str:
        return self.token


# --- Round 1: size guard --------------------------------------------------------------------------


def _size_guard(data: Mapping[str, Any], limits: Limits) -> list[tuple[str, str]]:
    """Count limits on the raw document (whatever is not a list or dict here, pydantic reports)."""
    errors: list[tuple[str, str]] = []
    objects = data.get("objects")
    if isinstance(objects, list):
        errors += _check_count("objects", len(objects), limits, "max_objects", "objects")
        triangles = sum(
            len(obj["triangles"])
            for obj in objects
            if isinstance(obj, dict) and isinstance(obj.get("triangles"), list)
        )
        errors += _check_count("objects", triangles, limits, "max_triangles", "triangles")
    lights = data.get("lights")
    if isinstance(lights, list):
        errors += _check_count("lights", len(lights), limits, "max_lights", "lights")
    materials = data.get("materials")
    if isinstance(materials, dict):
        errors += _check_count("materials", len(materials), limits, "max_materials", "materials")
    return errors


def _check_count(
    path: str, count: int, limits: Limits, field: str, noun: str
) -> list[tuple[str, str]]:
    limit = getattr(limits, field)
    if count <= limit:
        return []
    where = " over all meshes" if noun == "triangles" else ""
    return [(path, f"{count} {noun}{where} exceed the limit {limit} ({Limits.env_name(field)})")]


# --- Round 2: pydantic errors -> (path, message) --------------------------------------------------

_UNION_TAGS = {"objects": OBJECT_TYPES, "lights": LIGHT_TYPES, "materials": MATERIAL_TYPES}
_COLOUR_TAGS = ("rgb", "none") + TEXTURE_TYPES
_PAIRS = ("scale", "offset")  # a texture's (u, v) pairs
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_\-]*")


def format_path(loc: Iterable[int | str]) -> str:
    """``('objects', 3, 'radius')`` -> ``objects[3].radius``; odd keys are quoted (``x["a b"]``)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif _IDENTIFIER.fullmatch(part):
            out += f".{part}" if out else part
        else:
            out += f"[{json.dumps(part)}]"
    return out or ROOT


def _strip_union_tag(loc: tuple[int | str, ...]) -> tuple[int | str, ...]:
    # pydantic puts the tag of a discriminated union in the location:
    # ('objects', 3, 'sphere', 'radius'); users wrote objects[3].radius.
    if len(loc) >= 3 and loc[0] in _UNION_TAGS and loc[2] in _UNION_TAGS[loc[0]]:
        loc = loc[:2] + loc[3:]
    # and that of a colour parameter's branch: materials.m.albedo, a triple or a texture
    if len(loc) >= 4 and loc[0] == "materials" and loc[3] in _COLOUR_TAGS:
        loc = loc[:3] + loc[4:]
    return loc


def _number(x: Any) -> str:
    if isinstance(x, float) and x.is_integer():
        return str(int(x))
    return str(x)


def _quoted_names(expected: str) -> str:
    """``"'a', 'b' or 'c'"`` (pydantic's ctx) -> ``a, b, c``."""
    return ", ".join(re.findall(r"'([^']*)'", expected))


def _convert_validation_error(exc: ValidationError) -> list[tuple[str, str]]:
    errors: list[tuple[str, str]] = []
    short_tuples: set[str] = set()
    for err in exc.errors(include_url=False):
        loc = _strip_union_tag(tuple(err["loc"]))
        kind = err["type"]
        ctx = err.get("ctx") or {}
        value = err.get("input")

        if kind == "missing" and loc and isinstance(loc[-1], int):
            # A short tuple: pydantic names each missing element; report the list once.
            parent = format_path(loc[:-1])
            if parent not in short_tuples:
                short_tuples.add(parent)
                size = 2 if loc[-2] in _PAIRS or (len(loc) >= 3 and loc[-3] == "uvs") else 3
                errors.append((parent, f"must have exactly {size} elements, not {loc[-1]}"))
            continue
        if kind == "union_tag_not_found":
            names = ", ".join(_UNION_TAGS.get(str(loc[0]), ()))
            errors.append((format_path(loc + ("type",)), f"required field is missing ({names})"))
            continue
        errors.append((format_path(loc), _message(kind, err["msg"], ctx, value, loc)))
    return errors


def _message(
    kind: str, msg: str, ctx: dict[str, Any], value: Any, loc: tuple[int | str, ...]
) -> str:
    """A short, human message for one pydantic error (``msg``: pydantic's own)."""
    if isinstance(value, NonFiniteJSON) and kind != "extra_forbidden":
        return f"must be a finite number ({value.token} is not valid JSON)"
    simple = {
        "missing": "required field is missing",
        "extra_forbidden": "unknown field",
        "finite_number": "must be a finite number",
        "float_type": "must be a number",
        "float_parsing": "must be a number",
        "int_type": "must be an integer",
        "int_parsing": "must be an integer",
        "int_from_float": "must be an integer",
        "string_type": "must be a string",
        "list_type": "must be a list",
        "dict_type": "must be a JSON object",
        "model_type": "must be a JSON object",
        "model_attributes_type": "must be a JSON object",
    }
    if kind in simple:
        return simple[kind]
    bounds = {
        "greater_than": ("gt", ">"),
        "greater_than_equal": ("ge", ">="),
        "less_than": ("lt", "<"),
        "less_than_equal": ("le", "<="),
    }
    if kind in bounds:
        key, op = bounds[kind]
        return f"must be {op} {_number(ctx[key])}"
    if kind == "tuple_type":
        what = "vertex indices" if "triangles" in loc else "numbers"
        return f"must be a list of 3 {what}"
    if kind in ("too_short", "too_long"):
        n, actual = ctx.get("min_length", ctx.get("max_length")), ctx.get("actual_length")
        if ctx.get("field_type") == "Tuple":
            return f"must have exactly {n} elements, not {actual}"
        if kind == "too_short":
            return f"must have at least {n} element{'s' if n != 1 else ''}"
        return f"must have at most {n} elements, not {actual}"
    if kind == "union_tag_invalid":
        names = ", ".join(_UNION_TAGS.get(str(loc[0]), ())) or _quoted_names(ctx["expected_tags"])
        return f"unknown type {ctx['tag']!r} (expected one of: {names})"
    if kind == "literal_error":
        return f"unknown value {value!r} (expected one of: {_quoted_names(ctx['expected'])})"
    if kind == "scene":
        return str(ctx["message"])
    # Anything else: pydantic's own message, lower-cased to match ours.
    return msg[:1].lower() + msg[1:]


# --- Round 3: semantics ---------------------------------------------------------------------------


def _check_render_limits(scene: Scene, limits: Limits) -> list[tuple[str, str]]:
    errors: list[tuple[str, str]] = []
    width, height = scene.film.width, scene.film.height

    def over(path: str, value: int, field: str) -> None:
        limit = getattr(limits, field)
        if value > limit:
            errors.append((path, f"{value} exceeds the limit {limit} ({Limits.env_name(field)})"))

    over("film.width", width, "max_width")
    over("film.height", height, "max_height")
    if width * height > limits.max_pixels:
        errors.append(
            (
                "film",
                f"{width}x{height} = {width * height} pixels exceeds the limit {limits.max_pixels} "
                f"({Limits.env_name('max_pixels')})",
            )
        )
    over("render.spp", scene.render.spp, "max_spp")
    # -1 (unlimited, ended by Russian roulette) is always allowed.
    over("render.max_depth", scene.render.max_depth, "max_depth")
    return errors


def _check_material_references(scene: Scene) -> list[tuple[str, str]]:
    errors: list[tuple[str, str]] = []
    defined = ", ".join(sorted(scene.materials)) or "none"
    for i, obj in enumerate(scene.objects):
        if obj.material not in scene.materials:
            errors.append(
                (
                    f"objects[{i}].material",
                    f"unknown material {obj.material!r} (defined: {defined})",
                )
            )
    return errors


def _check_mesh(scene: Scene, i: int, mesh: Mesh, files: FileSource) -> list[tuple[str, str]]:
    """Read a file mesh, then check index range, degenerate triangles and closedness."""
    where = f"objects[{i}]"
    from_file = mesh.path is not None or mesh.asset is not None
    source_field = f"{where}.asset" if mesh.asset is not None else f"{where}.path"
    if from_file:
        loaded = _read_mesh_file(where, mesh, files)
        if isinstance(loaded, list):
            return loaded
        vertices, triangles, source = loaded
    else:
        vertices, triangles = mesh.arrays()
        source = None

    # Index range: a bad index would read outside the vertex array in the kernels.
    n_vertices = vertices.shape[0]
    bad = np.flatnonzero(((triangles < 0) | (triangles >= n_vertices)).any(axis=1))
    if bad.size:
        errors = []
        for t in bad[:MAX_REPORTED]:
            row = triangles[t]
            index = int(row[(row < 0) | (row >= n_vertices)][0])
            message = f"vertex index {index} out of range (the mesh has {n_vertices} vertices)"
            if from_file:
                errors.append((source_field, f"triangle {t}: {message}"))
            else:
                errors.append((f"{where}.triangles[{t}]", message))
        if bad.size > MAX_REPORTED:
            errors.append(
                (
                    source_field if from_file else f"{where}.triangles",
                    f"{bad.size - MAX_REPORTED} more triangles with out-of-range vertex indices",
                )
            )
        return errors

    # Texture coordinates and shading normals: one per vertex, finite; normals non-zero
    errors = _check_vertex_attributes(where, mesh, n_vertices, source_field if from_file else None)
    if errors:
        return errors

    # Triangles too large to compute with (an edge's squared length overflows): said as such,
    # from a file too, where a degenerate one would be dropped.
    degenerate, overflow = triangle_faults(vertices, triangles)
    if overflow.any():
        bad = np.flatnonzero(overflow)
        message = overflow_message("an edge of the triangle")
        errors = [
            (source_field, f"triangle {t}: {message}")
            if from_file
            else (f"{where}.triangles[{t}]", message)
            for t in bad[:MAX_REPORTED]
        ]
        if bad.size > MAX_REPORTED:
            errors.append(
                (
                    source_field if from_file else f"{where}.triangles",
                    f"{bad.size - MAX_REPORTED} more triangles that overflow",
                )
            )
        return errors

    # Degenerate triangles: errors inline (the user wrote them), dropped from files (real OBJ
    # files have a few, and they cannot be hit anyway).
    dropped = 0
    if degenerate.any():
        bad = np.flatnonzero(degenerate)
        if not from_file:
            errors = [
                (f"{where}.triangles[{t}]", "degenerate triangle (zero area)")
                for t in bad[:MAX_REPORTED]
            ]
            if bad.size > MAX_REPORTED:
                errors.append(
                    (f"{where}.triangles", f"{bad.size - MAX_REPORTED} more degenerate triangles")
                )
            return errors
        dropped = int(bad.size)
        triangles = triangles[~degenerate]
        if triangles.shape[0] == 0:
            return [(source_field, f"all {dropped} triangles are degenerate (zero area)")]

    if from_file:
        mesh._attach_arrays(vertices, triangles, dropped_degenerate=dropped, source_path=source)
        mesh.path = None

    # A medium needs an inside: every edge must be shared by exactly two triangles that run it
    # in opposite directions (closed, consistently oriented 2-manifold).
    material = scene.materials.get(mesh.material)
    if material is not None and material.type in VOLUME_MATERIAL_TYPES:
        problem = find_open_edge(triangles)
        if problem is not None:
            return [(where, f"a {material.type} mesh must be {problem}")]
    return []


def _check_vertex_attributes(where: str, mesh: Mesh, n_vertices: int,
                             file_field: str | None) -> list[tuple[str, str]]:
    """A mesh's ``uvs`` and ``normals``: one per vertex, finite, normals not zero (errors on the
    field, or on the file's reference for a mesh read from one)."""
    errors = []
    for name, values in (("uvs", mesh.uv_array()), ("normals", mesh.model_normal_array())):
        if values is None:
            continue
        field = file_field or f"{where}.{name}"
        what = name if file_field is None else f"its {name}"
        if len(values) != n_vertices:
            errors.append((field, f"{what}: {len(values)} given for {n_vertices} vertices (one "
                           "per vertex)"))
            continue
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            errors.append((field if file_field else f"{field}[{bad[0]}]",
                           f"{what}: not a finite number" + (f" (vertex {bad[0]})"
                                                             if file_field else "")))
            continue
        if name == "normals":
            bad = np.flatnonzero(~(np.abs(values).max(axis=1) > 0.0))
            if bad.size:
                errors.append((field if file_field else f"{field}[{bad[0]}]",
                               f"{what}: a zero vector cannot be a normal"
                               + (f" (vertex {bad[0]})" if file_field else "")))
    return errors


def _read_mesh_file(
    where: str, mesh: Mesh, files: FileSource
) -> list[tuple[str, str]] | tuple[np.ndarray, np.ndarray, Path | None]:
    """(vertices, triangles, resolved path or None for an asset), or the errors (on the mesh's
    ``path``, or on its ``asset``)."""
    if mesh.asset is not None:
        field = f"{where}.asset"
        read = files.read(AssetRef(asset=mesh.asset), where, MESH_KINDS)
    else:
        assert mesh.path is not None
        field = f"{where}.path"
        read = files.read(mesh.path, field, MESH_KINDS)
    if isinstance(read, list):
        return read
    data, kind, label = read
    try:
        # Lazily: the mesh reader is needed only for scenes that use it.
        from renderer.geometry.meshio import parse_mesh
    except ImportError as exc:
        return [(field, f"mesh files cannot be read here ({exc})")]
    try:
        vertices, triangles, uvs, normals = parse_mesh(data, kind, name=label)
    except Exception as exc:  # a malformed file: report it, whatever the reader raised
        text = str(exc)
        return [(field, text if label in text else f"{label!r}: {text}")]

    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        return [(field, f"{label!r}: vertices must have shape (V, 3)")]
    if triangles.ndim != 2 or triangles.shape[1] != 3 or triangles.shape[0] == 0:
        return [(field, f"{label!r}: no triangles")]
    if not np.isfinite(vertices).all():
        return [(field, f"{label!r}: vertex coordinates must be finite numbers")]
    source = None if mesh.asset is not None else Path(label)
    mesh._attach_attributes(uvs, normals)
    return vertices, triangles.astype(np.int64, copy=False), source


# --- Environment ---------------------------------------------------------------------------------


def _check_environment(scene: Scene, files: FileSource, limits: Limits) -> list[tuple[str, str]]:
    """Read the environment image and check it: exclusive with ``background``, a float image of
    3 colour channels within the size limits, every texel finite and ≥ 0."""
    env = scene.environment
    assert env is not None
    errors = []
    if "background" in scene.model_fields_set:
        errors.append(("environment", "exclusive with background: give one or the other"))
    read = files.read(env.image, "environment.image", ENVIRONMENT_KINDS)
    if isinstance(read, list):
        return errors + read
    data, kind, label = read
    field = "environment.image" + (".asset" if isinstance(env.image, AssetRef) else "")
    try:
        # Lazily: the image readers (and the OpenEXR library) only for scenes that use them
        from renderer.film.image_io import decode_hdr_image

        pixels = decode_hdr_image(data, kind, name=label)
    except ValueError as exc:
        return errors + [(field, str(exc))]
    height, width = pixels.shape[:2]
    side = limits.max_environment_side
    if width > side or height > side:
        return errors + [(field, f"{label}: {width}x{height} texels exceed the limit {side} per "
                          f"side ({Limits.env_name('max_environment_side')})")]
    if width * height > limits.max_texels:
        return errors + [(field, f"{label}: {width}x{height} = {width * height} texels exceed the "
                          f"limit {limits.max_texels} ({Limits.env_name('max_texels')})")]
    if height < 2:
        return errors + [(field, f"{label}: an environment image needs at least 2 rows (one "
                          "for each pole)")]
    bad = ~np.isfinite(pixels)
    if bad.any():
        y, x, c = np.argwhere(bad)[0]
        return errors + [(field, f"{label}: {int(bad.any(axis=2).sum())} texels are not finite "
                          f"numbers (the first at row {y}, column {x}: {pixels[y, x, c]})")]
    negative = pixels < 0.0
    if negative.any():
        y, x, c = np.argwhere(negative)[0]
        return errors + [(field, f"{label}: {int(negative.any(axis=2).sum())} texels are "
                          f"negative (the first at row {y}, column {x}: {pixels[y, x, c]:g}); "
                          "radiance must be ≥ 0")]
    if not errors:
        env._attach_pixels(pixels)
    return errors


# --- Textures ------------------------------------------------------------------------------------


def _check_textures(scene: Scene, files: FileSource, limits: Limits) -> list[tuple[str, str]]:
    """Read every bitmap texture (each file once) and check it: a PNG, EXR or PFM within the side
    limit, its texels finite, ≥ 0, and ≤ 1 on a reflectance (``Albedo``) parameter; the texels of
    all textures and the environment together within ``max_texels``; a phong whose lobes are
    textured keeps diffuse + specular ≤ 1 texel by texel."""
    errors: list[tuple[str, str]] = []
    env = scene.environment
    texels = env.pixels().shape[0] * env.pixels().shape[1] if (
        env is not None and env._pixels is not None) else 0
    read: dict[str, np.ndarray] = {}  # the images read, by reference and srgb
    for name, m in scene.materials.items():
        for param in COLOUR_PARAMS.get(m.type, ()):
            tex = getattr(m, param)
            if not isinstance(tex, BitmapTexture):
                continue
            where = f"materials.{format_path([name])}.{param}.image"
            field = where + (".asset" if isinstance(tex.image, AssetRef) else "")
            key = json.dumps([tex.image if isinstance(tex.image, str) else tex.image.asset,
                              tex.srgb])
            if key not in read:
                got = files.read(tex.image, where, TEXTURE_KINDS)
                if isinstance(got, list):
                    errors += got
                    continue
                data, kind, label = got
                try:
                    from renderer.film.image_io import decode_texture

                    pixels = decode_texture(data, kind, srgb=tex.srgb, name=label)
                except ValueError as exc:
                    errors.append((field, str(exc)))
                    continue
                height, width = pixels.shape[:2]
                side = limits.max_texture_side
                if width > side or height > side:
                    errors.append((field, f"{label}: {width}x{height} texels exceed the limit "
                                   f"{side} per side ({Limits.env_name('max_texture_side')})"))
                    continue
                texels += width * height
                if texels > limits.max_texels:
                    errors.append((field, f"{label}: {width}x{height} texels bring the scene's "
                                   f"images to {texels} texels, over the limit "
                                   f"{limits.max_texels} ({Limits.env_name('max_texels')})"))
                    continue
                bad = ~np.isfinite(pixels)
                if bad.any():
                    y, x, c = np.argwhere(bad)[0]
                    errors.append((field, f"{label}: {int(bad.any(axis=2).sum())} texels are not "
                                   f"finite numbers (the first at row {y}, column {x}: "
                                   f"{pixels[y, x, c]})"))
                    continue
                read[key] = pixels
            pixels = read[key]
            limit_one = param != "specular" or m.type == "phong"  # conductor.specular: ≥ 0
            low, high = float(pixels.min()), float(pixels.max())
            if low < 0.0 or (limit_one and high > 1.0):
                bound = "in [0, 1]" if limit_one else "≥ 0"
                errors.append((field, f"texels must be {bound} for {param} (found "
                               f"{low:g} to {high:g})"))
                continue
            tex._attach_pixels(pixels)
        if m.type == "translucent":
            m._read_texture()
        if m.type == "phong" and not errors:
            errors += _check_phong_texels(name, m)
    return errors


def _check_phong_texels(name: str, m) -> list[tuple[str, str]]:
    """diffuse + specular ≤ 1 with a textured lobe: the largest texel of each bounds the sum."""
    from renderer.textures import texture_max

    kd, ks = texture_max(m.diffuse), texture_max(m.specular)
    if any(d + s > 1.0 + 1e-6 for d, s in zip(kd, ks, strict=True)):
        return [(f"materials.{format_path([name])}", "diffuse + specular must be <= 1 in every "
                 f"channel (energy conservation): the brightest texels reach "
                 f"{format_rgb(kd)} + {format_rgb(ks)}")]
    return []


def format_rgb(c) -> str:
    return "[" + ", ".join(f"{x:.3g}" for x in c) + "]"


# --- Mesh checks (vectorized) ---------------------------------------------------------------------


def degenerate_triangles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Boolean mask (T,) of zero-area triangles: |e1 x e2| <= eps * (two longest edges)."""
    return triangle_faults(vertices, triangles)[0]


def triangle_faults(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (T,): degenerate triangles (zero area: |e1 x e2| <= eps * (product of the
    two longest edges)), and triangles that overflow (an edge's squared length is not a finite
    float: the renderer cannot compute with it; ``schema.overflows``). An overflowing triangle is
    not called degenerate."""
    degenerate = np.empty(triangles.shape[0], dtype=bool)
    overflow = np.empty(triangles.shape[0], dtype=bool)
    for start in range(0, triangles.shape[0], _BLOCK):
        p = vertices[triangles[start : start + _BLOCK]]  # (n, 3 corners, xyz)
        block = slice(start, start + p.shape[0])
        with np.errstate(over="ignore", invalid="ignore"):  # the overflow is what is looked for
            e1, e2, e3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 2] - p[:, 1]
            big = ~np.isfinite(
                np.maximum.reduce([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3)])
            )
        overflow[block] = big
        # The test is scale-free: on the edges over their largest component, whose products
        # cannot overflow (an area of 1e200 x 1e200 would be inf <= inf: "degenerate").
        scale = np.maximum.reduce([np.abs(e).max(axis=1) for e in (e1, e2, e3)])
        scale[big | (scale == 0.0)] = 1.0
        e1, e2, e3 = (np.where(big[:, None], 0.0, e) / scale[:, None] for e in (e1, e2, e3))
        # Squared on both sides: no square roots. |e1 x e2|² = (2 area)².
        cx = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        cy = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        cz = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        twice_area_sq = cx * cx + cy * cy + cz * cz
        a, b, c = (np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3))
        longest_pair_sq = np.maximum(np.maximum(a * b, a * c), b * c)
        degenerate[block] = ~big & (twice_area_sq <= EPS_DEGENERATE**2 * longest_pair_sq)
    return degenerate, overflow


def find_open_edge(triangles: np.ndarray) -> str | None:
    """None if the mesh is closed and consistently oriented, else what is wrong (first edge in
    (lo, hi) order): "closed (edge (3, 7) is used by 1 triangle)" or "consistently oriented ..."."""
    # Directed edges a->b of every triangle, keyed by their undirected edge lo * n + hi.
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    lo, hi = edges.min(axis=1), edges.max(axis=1)
    n = int(hi.max()) + 1
    key = lo * n + hi  # < n² <= (3 * 4M)² < 2**63
    forward = edges[:, 0] < edges[:, 1]
    order = np.argsort(key, kind="stable")
    key, forward = key[order], forward[order]

    # Runs of equal keys: one run per undirected edge.
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[start, key.size])
    wrong_count = count != 2
    # Used twice, but in the same direction: neighbours disagree on the winding.
    same_way = np.zeros_like(wrong_count)
    two = np.flatnonzero(count == 2)
    same_way[two] = forward[start[two]] == forward[start[two] + 1]

    bad = wrong_count | same_way
    if not bad.any():
        return None
    first = int(np.flatnonzero(bad)[0])
    edge = f"edge ({int(key[start[first]] // n)}, {int(key[start[first]] % n)})"
    if wrong_count[first]:
        used = int(count[first])
        return f"closed ({edge} is used by {used} triangle{'s' if used != 1 else ''})"
    return (
        f"consistently oriented ({edge} runs the same way in both of its triangles: "
        "flip one so that neighbours agree)"
    )
