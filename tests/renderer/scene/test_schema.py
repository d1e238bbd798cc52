"""Scene schema, loading and validation: every error names its JSON path and a short message."""

from __future__ import annotations

import copy
import json
import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from renderer.geometry import meshgen
from renderer.scene import Limits, Scene, SceneError, load_scene, load_scene_file
from renderer.scene.load import degenerate_triangles, find_open_edge, triangle_faults
from renderer.scene.schema import (
    Box,
    Camera,
    DielectricMaterial,
    DiffuseMaterial,
    Mesh,
    PhongMaterial,
    Quad,
    RenderSettings,
    Sphere,
    TranslucentMaterial,
)

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"

# A closed tetrahedron, counter-clockwise seen from outside.
TET_VERTICES = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
TET_TRIANGLES = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


@pytest.fixture(autouse=True)
def _no_limit_env(monkeypatch):
    """Tests start from the default limits, whatever the environment of the run."""
    for name in Limits.model_fields:
        monkeypatch.delenv(Limits.env_name(name), raising=False)


def scene_dict(**overrides):
    """A small valid scene; keyword arguments replace top-level entries."""
    data = {
        "camera": {"position": [0, 0, 3.9], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 39.0},
        "film": {"width": 16, "height": 12},
        "render": {"spp": 4, "max_depth": 8, "seed": 1},
        "materials": {
            "white": {"type": "diffuse", "albedo": [0.73, 0.73, 0.73]},
            "red": {"type": "diffuse", "albedo": [0.63, 0.065, 0.05]},
            "wax": {"type": "translucent", "albedo": [0.95, 0.85, 0.7], "density": 6.0},
            "glass": {"type": "dielectric", "ior": 1.5},
        },
        "objects": [
            {"type": "sphere", "center": [0, -0.5, 0], "radius": 0.5, "material": "wax"},
            {
                "type": "quad",
                "origin": [-0.25, 0.99, -0.25],
                "edge1": [0.5, 0, 0],
                "edge2": [0, 0, 0.5],
                "material": "white",
                "emission": [17, 12, 4],
            },
        ],
        "lights": [{"type": "point", "position": [1, 2, 1], "intensity": [3, 3, 3]}],
    }
    data.update(copy.deepcopy(overrides))
    return data


def tet_mesh(material="glass", vertices=TET_VERTICES, triangles=TET_TRIANGLES):
    return {"type": "mesh", "material": material, "vertices": vertices, "triangles": triangles}


def errors_of(data, **kwargs) -> list[tuple[str, str]]:
    with pytest.raises(SceneError) as info:
        load_scene(data, **kwargs)
    return info.value.errors


def torus(nu: int, nv: int, big_r: float = 1.0, small_r: float = 0.3):
    """A closed, consistently oriented torus grid: 2 * nu * nv triangles."""
    return meshgen.torus(big_r, small_r, nu, nv, axis="z")


# --- Valid scenes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.json")), ids=lambda p: p.name)
def test_examples_load(path):
    scene = load_scene_file(path)
    assert isinstance(scene, Scene)
    assert scene.objects and scene.materials
    data = json.loads(path.read_text())
    if any("path" in obj for obj in data["objects"]):
        # Mesh files are for the command line only: the HTTP-style load refuses them by name
        with pytest.raises(SceneError, match=r"objects\[\d+\]\.path"):
            load_scene(data)
    else:
        # model_dump, not ==: pydantic's == also compares the meshes' numpy arrays
        assert load_scene(data).model_dump() == scene.model_dump()


def test_examples_exist():
    assert len(list(EXAMPLES.glob("*.json"))) >= 2


def test_defaults():
    data = scene_dict()
    del data["render"], data["lights"], data["camera"]["up"], data["camera"]["fov"]
    data["materials"] = {
        "m": {"type": "diffuse"},
        "p": {"type": "phong"},
        "mi": {"type": "mirror"},
        "d": {"type": "dielectric"},
        "t": {"type": "translucent"},
    }
    data["objects"] = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]
    scene = load_scene(data)
    assert scene.render == RenderSettings(spp=64, max_depth=-1, seed=0)
    assert scene.background == (0, 0, 0)
    assert scene.lights == []
    assert scene.camera.up == (0, 1, 0) and scene.camera.fov == 39.0
    assert scene.materials["m"] == DiffuseMaterial(albedo=(0.5, 0.5, 0.5))
    assert scene.materials["p"] == PhongMaterial(
        diffuse=(0.5, 0.5, 0.5), specular=(0.2, 0.2, 0.2), exponent=30
    )
    assert scene.materials["mi"].reflectance == (1, 1, 1)
    assert scene.materials["d"] == DielectricMaterial(ior=1.5, absorption=(0, 0, 0))
    t = scene.materials["t"]
    assert (t.method, t.ior, t.g) == ("volumetric", 1.3, 0.0)
    assert t.albedo_rgb == (0.8, 0.8, 0.8) and t.sigma_t == (1.0, 1.0, 1.0) and not t.chromatic
    assert t == TranslucentMaterial()
    assert isinstance(scene.objects[0], Sphere) and scene.objects[0].emission is None


@pytest.mark.parametrize(
    "method", ["volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion", "auto"]
)
def test_every_translucent_method_is_accepted(method):
    data = scene_dict()
    data["materials"]["wax"]["method"] = method
    assert load_scene(data).materials["wax"].method == method


def test_edge_values_are_accepted():
    data = scene_dict()
    data["materials"]["glass"]["ior"] = 0.5  # any ior > 0 (e.g. a bubble in water)
    data["materials"]["wax"] |= {"ior": 1.0, "g": -0.999, "albedo": [0, 1, 1]}
    data["materials"]["ph"] = {"type": "phong", "diffuse": [0.7, 0.5, 0], "specular": [0.3, 0.5, 1]}
    data["render"] = {"spp": 1, "max_depth": -1, "seed": 2**63 - 1}
    data["camera"]["fov"] = 179.9
    data["film"] = {"width": 1, "height": 1}
    data["objects"][0]["radius"] = 1  # integers are numbers
    load_scene(data)


# --- Structural errors: exact paths and messages --------------------------------------------------


def mutate(fn):
    data = scene_dict()
    fn(data)
    return data


def _set(path, value):
    """A mutation setting data[path[0]][path[1]]... = value."""

    def apply(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return apply


def _delete(path):
    def apply(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return apply


DENSITY_MESSAGE = "must be a number > 0, or a list of 3 numbers > 0 (σt of each channel)"
STRUCTURAL_CASES = [
    (_set(("objects", 0, "radius"), 0), "objects[0].radius", "must be > 0"),
    (_set(("objects", 0, "radius"), -1), "objects[0].radius", "must be > 0"),
    (_set(("materials", "wax", "albedo", 1), 1.5), "materials.wax.albedo[1]", "must be <= 1"),
    (_set(("materials", "red", "albedo", 0), -0.1), "materials.red.albedo[0]", "must be >= 0"),
    (_set(("film", "width"), 0), "film.width", "must be >= 1"),
    (_set(("film", "height"), 2.5), "film.height", "must be an integer"),
    (_set(("render", "spp"), 0), "render.spp", "must be >= 1"),
    (_set(("render", "spp"), 4.0), "render.spp", "must be an integer"),
    (_set(("render", "spp"), "64"), "render.spp", "must be an integer"),
    (_set(("render", "max_depth"), -2), "render.max_depth", "must be >= -1"),
    (_set(("render", "seed"), -1), "render.seed", "must be >= 0"),
    (_set(("render", "sampler"), "halton"), "render.sampler",
     "unknown value 'halton' (expected one of: independent, sobol)"),
    (_set(("render", "seed"), 2**63), "render.seed", "must be <= 9223372036854775807"),
    (_set(("camera", "fov"), 0), "camera.fov", "must be > 0"),
    (_set(("camera", "fov"), 180), "camera.fov", "must be < 180"),
    (_set(("camera", "up"), [0, 0, 0]), "camera.up", "must be a non-zero vector"),
    (_set(("camera", "look_at"), [0, 0, 3.9]), "camera", "look_at must differ from position"),
    (
        _set(("camera", "up"), [0, 0, -2]),
        "camera",
        "up [0, 0, -2] is parallel to the viewing direction [0, 0, -3.9] (look_at - position)",
    ),
    (_delete(("camera", "position")), "camera.position", "required field is missing"),
    (
        _set(("camera", "position"), [0, 0]),
        "camera.position",
        "must have exactly 3 elements, not 2",
    ),
    (_set(("camera", "position"), []), "camera.position", "must have exactly 3 elements, not 0"),
    (
        _set(("camera", "position"), [0, 0, 1, 1]),
        "camera.position",
        "must have exactly 3 elements, not 4",
    ),
    (_set(("camera", "position"), 3), "camera.position", "must be a list of 3 numbers"),
    (_set(("camera", "position", 1), "0"), "camera.position[1]", "must be a number"),
    (_set(("camera", "position", 1), True), "camera.position[1]", "must be a number"),
    (_set(("camera", "position", 1), None), "camera.position[1]", "must be a number"),
    (
        _set(("camera", "position", 2), float("nan")),
        "camera.position[2]",
        "must be a finite number",
    ),
    (_set(("objects", 0, "radius"), float("inf")), "objects[0].radius", "must be a finite number"),
    (_set(("background",), [0, -1, 0]), "background[1]", "must be >= 0"),
    (_set(("objects", 1, "emission", 2), -4), "objects[1].emission[2]", "must be >= 0"),
    (_set(("objects", 0, "radus"), 1), "objects[0].radus", "unknown field"),
    (_set(("camera", "fov_y"), 40), "camera.fov_y", "unknown field"),
    (_set(("colour",), [1, 1, 1]), "colour", "unknown field"),
    (_set(("materials", "wax", "sigma"), 2), "materials.wax.sigma", "unknown field"),
    (_delete(("objects", 0, "radius")), "objects[0].radius", "required field is missing"),
    (_delete(("objects", 0, "material")), "objects[0].material", "required field is missing"),
    (_set(("objects", 0, "material"), 3), "objects[0].material", "must be a string"),
    (_delete(("film",)), "film", "required field is missing"),
    (_delete(("materials",)), "materials", "required field is missing"),
    (_set(("film",), [16, 12]), "film", "must be a JSON object"),
    (_set(("materials",), []), "materials", "must be a JSON object"),
    (_set(("objects",), {}), "objects", "must be a list"),
    (_set(("objects",), []), "objects", "must have at least 1 element"),
    (_set(("objects", 0), 5), "objects[0]", "must be a JSON object"),
    (
        _set(("objects", 0, "type"), "spehre"),
        "objects[0]",
        "unknown type 'spehre' (expected one of: sphere, quad, box, mesh)",
    ),
    (
        _delete(("objects", 0, "type")),
        "objects[0].type",
        "required field is missing (sphere, quad, box, mesh)",
    ),
    (
        _set(("materials", "wax", "type"), "glass"),
        "materials.wax",
        "unknown type 'glass' (expected one of: diffuse, phong, mirror, conductor, dielectric, "
        "translucent)",
    ),
    (
        _set(("lights", 0, "type"), "spot"),
        "lights[0]",
        "unknown type 'spot' (expected one of: point, directional)",
    ),
    (_delete(("lights", 0, "intensity")), "lights[0].intensity", "required field is missing"),
    (
        _set(("lights", 0), {"type": "directional", "direction": [0, 0, 0], "irradiance": [1] * 3}),
        "lights[0].direction",
        "must be a non-zero vector",
    ),
    (
        _set(("materials", "wax", "method"), "magic"),
        "materials.wax.method",
        "unknown value 'magic' (expected one of: volumetric, single_scatter, diffuse_entry, "
        "backlight, diffusion, auto)",
    ),
    (_set(("materials", "wax", "g"), 1), "materials.wax.g", "must be < 1"),
    (_set(("materials", "wax", "g"), -1), "materials.wax.g", "must be > -1"),
    (_set(("materials", "wax", "ior"), 0.9), "materials.wax.ior", "must be >= 1"),
    (_set(("materials", "wax", "density"), 0), "materials.wax.density", DENSITY_MESSAGE),
    (_set(("materials", "wax", "density"), [1, 0, 1]), "materials.wax.density", DENSITY_MESSAGE),
    (_set(("materials", "wax", "density"), [1, 2]), "materials.wax.density", DENSITY_MESSAGE),
    (_set(("materials", "wax", "sigma_z"), 1), "materials.wax.sigma_z", "unknown field"),
    (_set(("materials", "wax", "sigma_s"), [1, -1, 1]), "materials.wax.sigma_s[1]",
     "must be >= 0"),
    (_set(("materials", "wax"), {"type": "translucent", "sigma_s": [1, 1, 1]}), "materials.wax",
     "sigma_s needs sigma_a too (or give albedo and density)"),
    (_set(("materials", "wax"), {"type": "translucent", "sigma_s": [1, 1, 1],
                                 "sigma_a": [0, 0, 0], "albedo": [1, 1, 1]}), "materials.wax",
     "sigma_s and sigma_a replace albedo and density; give one form (given: albedo, sigma_s, "
     "sigma_a)"),
    (_set(("materials", "wax"), {"type": "translucent", "sigma_s": [1, 0, 1],
                                 "sigma_a": [0, 0, 1]}), "materials.wax",
     "sigma_s + sigma_a must be > 0 in every channel (green: 0 + 0)"),
    (_set(("materials", "wax"), {"type": "translucent", "preset": "jade"}),
     "materials.wax.preset", "unknown preset 'jade'; known: apple, chicken1, chicken2, cream, "
     "ketchup, marble, potato, skimmilk, skin1, skin2, wholemilk"),
    (_set(("materials", "wax"), {"type": "translucent", "preset": "skin1", "density": 2}),
     "materials.wax", "preset replaces albedo, density, sigma_s and sigma_a; give one form (also "
     "given: density)"),
    (_set(("materials", "wax"), {"type": "translucent", "preset_scale": 10}), "materials.wax",
     "preset_scale applies to a preset only"),
    (_set(("materials", "wax"), {"type": "translucent", "preset": "skin1", "preset_scale": 0}),
     "materials.wax.preset_scale", "must be > 0"),
    (_set(("materials", "glass", "ior"), 0), "materials.glass.ior", "must be > 0"),
    (
        _set(("materials", "glass", "absorption"), [0, -1, 0]),
        "materials.glass.absorption[1]",
        "must be >= 0",
    ),
    (
        _set(
            ("materials", "p"), {"type": "phong", "diffuse": [0.5, 0.8, 0.5], "specular": [0.5] * 3}
        ),
        "materials.p",
        "diffuse + specular must be <= 1 in every channel (energy conservation): "
        "green is 0.8 + 0.5 = 1.3",
    ),
    (
        _set(("materials", "p"), {"type": "phong", "exponent": 0}),
        "materials.p.exponent",
        "must be > 0",
    ),
    (
        _set(("materials", "m"), {"type": "mirror", "reflectance": [1.2, 1, 1]}),
        "materials.m.reflectance[0]",
        "must be <= 1",
    ),
    (
        _set(("materials", "my wax"), {"type": "diffuse", "albedo": [2, 0, 0]}),
        'materials["my wax"].albedo[0]',
        "must be <= 1",
    ),
    (
        _set(("objects", 1, "edge2"), [1, 0, 0]),
        "objects[1]",
        "degenerate quad: edge1 and edge2 are parallel or zero",
    ),
    (
        _set(("objects", 1, "edge2"), [0, 0, 0]),
        "objects[1]",
        "degenerate quad: edge1 and edge2 are parallel or zero",
    ),
    (
        _set(("objects", 1, "edge2"), [-1e-3, 1e-16, 0]),  # nearly anti-parallel
        "objects[1]",
        "degenerate quad: edge1 and edge2 are parallel or zero",
    ),
    (
        _set(
            ("objects", 1), {"type": "box", "min": [0, 0, 0], "max": [1, 1, 0], "material": "red"}
        ),
        "objects[1]",
        "min must be < max in every component: z has min 0 >= max 0",
    ),
    (
        _set(
            ("objects", 1),
            {
                "type": "box",
                "min": [0, 0, 0],
                "max": [1, 1, 1],
                "material": "red",
                "rotate": {"axis": [0, 0, 0], "angle": 30},
            },
        ),
        "objects[1].rotate.axis",
        "must be a non-zero vector",
    ),
    (
        _set(
            ("objects", 1),
            {
                "type": "box",
                "min": [0, 0, 0],
                "max": [1, 1, 1],
                "material": "red",
                "rotate": {"axis": [0, 1, 0]},
            },
        ),
        "objects[1].rotate.angle",
        "required field is missing",
    ),
    (
        _set(("objects", 1), tet_mesh() | {"triangles": [[0, 1, -1]]}),
        "objects[1].triangles[0][2]",
        "must be >= 0",
    ),
    (
        _set(("objects", 1), tet_mesh() | {"triangles": [[0, 1]]}),
        "objects[1].triangles[0]",
        "must have exactly 3 elements, not 2",
    ),
    (
        _set(("objects", 1), tet_mesh() | {"triangles": [[0, 1, 2.0]]}),
        "objects[1].triangles[0][2]",
        "must be an integer",
    ),
    (
        _set(("objects", 1), tet_mesh() | {"triangles": []}),
        "objects[1].triangles",
        "must have at least 1 element",
    ),
    (
        _set(("objects", 1), {"type": "mesh", "material": "red", "vertices": TET_VERTICES}),
        "objects[1]",
        "vertices given without triangles",
    ),
    (
        _set(("objects", 1), {"type": "mesh", "material": "red"}),
        "objects[1]",
        "a mesh needs vertices and triangles, or asset (or, from the CLI, path)",
    ),
]


@pytest.mark.parametrize(
    ("change", "path", "message"),
    STRUCTURAL_CASES,
    ids=[f"{path}: {message[:40]}" for _, path, message in STRUCTURAL_CASES],
)
def test_structural_error(change, path, message):
    errors = errors_of(mutate(change))
    assert (path, message) in errors, errors


def test_the_valid_base_scene_loads():
    # Guards the parametrized cases above: each of them fails because of its one change.
    scene = load_scene(scene_dict())
    assert isinstance(scene.objects[1], Quad)


def test_structural_errors_are_all_reported():
    data = scene_dict()
    data["objects"][0]["radius"] = -1
    data["objects"][1]["type"] = "quadd"
    data["film"]["width"] = 0
    data["materials"]["white"]["albedo"] = [0.5, 2, 0.5]
    errors = errors_of(data)
    assert errors == [
        ("film.width", "must be >= 1"),
        ("materials.white.albedo[1]", "must be <= 1"),
        ("objects[0].radius", "must be > 0"),
        ("objects[1]", "unknown type 'quadd' (expected one of: sphere, quad, box, mesh)"),
    ]


def test_top_level_must_be_an_object():
    for data in ([], "scene", None, 3):
        assert errors_of(data) == [("(root)", "a scene must be a JSON object")]


def test_mesh_path_rejected_without_allow_paths():
    data = scene_dict(objects=[{"type": "mesh", "material": "red", "path": "bunny.obj"}])
    assert errors_of(data) == [
        (
            "objects[0].path",
            "file paths are accepted only by the command line; send vertices and triangles "
            'inline, or upload the file (POST /api/assets) and give "asset"',
        )
    ]
    # Nor through the bare model (a server that skipped load_scene would still not read files).
    with pytest.raises(ValueError, match="accepted only by the command line"):
        Scene.model_validate(data)


def test_mesh_with_both_path_and_vertices():
    data = scene_dict(objects=[tet_mesh("red") | {"path": "bunny.obj"}])
    errors = errors_of(data, allow_paths=True)
    assert errors == [
        ("objects[0]", "give one of vertices and triangles, path or asset, not vertices and "
         "triangles and path")
    ]


# --- Semantic errors ------------------------------------------------------------------------------


def test_unknown_material_names_the_defined_ones():
    data = scene_dict()
    data["materials"] = {"red": data["materials"]["red"], "white": data["materials"]["white"]}
    data["objects"][0]["material"] = "wax"
    data["objects"].append({"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "foo"})
    assert errors_of(data) == [
        ("objects[0].material", "unknown material 'wax' (defined: red, white)"),
        ("objects[2].material", "unknown material 'foo' (defined: red, white)"),
    ]


def test_semantic_errors_are_all_collected():
    data = scene_dict(film={"width": 10000, "height": 10000})
    data["render"]["spp"] = 100_000
    data["objects"][0]["material"] = "foo"
    data["objects"].append(tet_mesh("red", triangles=[[0, 1, 2], [0, 1, 7]]))
    data["objects"].append(tet_mesh("glass", triangles=TET_TRIANGLES[:3]))
    assert errors_of(data) == [
        ("film.width", "10000 exceeds the limit 8192 (LUCENT_MAX_WIDTH)"),
        ("film.height", "10000 exceeds the limit 8192 (LUCENT_MAX_HEIGHT)"),
        ("film", "10000x10000 = 100000000 pixels exceeds the limit 16777216 (LUCENT_MAX_PIXELS)"),
        ("render.spp", "100000 exceeds the limit 65536 (LUCENT_MAX_SPP)"),
        ("objects[0].material", "unknown material 'foo' (defined: glass, red, wax, white)"),
        ("objects[2].triangles[1]", "vertex index 7 out of range (the mesh has 4 vertices)"),
        ("objects[3]", "a dielectric mesh must be closed (edge (1, 2) is used by 1 triangle)"),
    ]


def test_scene_error_format_and_pickle():
    error = SceneError([("objects[3].radius", "must be > 0"), ("film", "too big")])
    assert str(error) == "objects[3].radius: must be > 0\nfilm: too big"
    assert isinstance(error, ValueError)
    assert error.as_dicts()[0] == {"path": "objects[3].radius", "message": "must be > 0"}
    again = pickle.loads(pickle.dumps(error))
    assert again.errors == error.errors and str(again) == str(error)
    assert SceneError("(root)", "a scene must be a JSON object").errors == [
        ("(root)", "a scene must be a JSON object")
    ]


# --- Limits ---------------------------------------------------------------------------------------


def test_limits_defaults():
    limits = Limits()
    assert (limits.max_width, limits.max_height, limits.max_pixels) == (8192, 8192, 4096**2)
    assert (limits.max_spp, limits.max_depth) == (65_536, 100_000)
    assert (limits.max_objects, limits.max_triangles) == (10_000, 4_000_000)
    assert (limits.max_lights, limits.max_materials) == (1_000, 1_000)
    assert Limits.env_name("max_spp") == "LUCENT_MAX_SPP"


def test_spp_limit_from_environment(monkeypatch):
    data = scene_dict(render={"spp": 129})
    load_scene(data)
    monkeypatch.setenv("LUCENT_MAX_SPP", "128")
    assert Limits().max_spp == 128
    assert errors_of(data) == [("render.spp", "129 exceeds the limit 128 (LUCENT_MAX_SPP)")]
    data["render"]["spp"] = 128
    load_scene(data)


def test_limits_argument_wins_over_environment(monkeypatch):
    monkeypatch.setenv("LUCENT_MAX_SPP", "1000000")
    data = scene_dict(render={"spp": 5})
    assert errors_of(data, limits=Limits(max_spp=4)) == [
        ("render.spp", "5 exceeds the limit 4 (LUCENT_MAX_SPP)")
    ]


def test_film_limits():
    limits = Limits(max_width=100, max_height=50, max_pixels=1000)
    assert errors_of(scene_dict(film={"width": 101, "height": 9}), limits=limits) == [
        ("film.width", "101 exceeds the limit 100 (LUCENT_MAX_WIDTH)"),
    ]
    assert errors_of(scene_dict(film={"width": 100, "height": 51}), limits=limits) == [
        ("film.height", "51 exceeds the limit 50 (LUCENT_MAX_HEIGHT)"),
        ("film", "100x51 = 5100 pixels exceeds the limit 1000 (LUCENT_MAX_PIXELS)"),
    ]
    load_scene(scene_dict(film={"width": 100, "height": 10}), limits=limits)


def test_depth_limit_allows_unlimited():
    limits = Limits(max_depth=10)
    load_scene(scene_dict(render={"max_depth": -1}), limits=limits)
    load_scene(scene_dict(render={"max_depth": 10}), limits=limits)
    assert errors_of(scene_dict(render={"max_depth": 11}), limits=limits) == [
        ("render.max_depth", "11 exceeds the limit 10 (LUCENT_MAX_DEPTH)")
    ]


def test_count_limits_are_checked_before_parsing():
    data = scene_dict()
    data["objects"] = [data["objects"][0]] * 3 + [tet_mesh("red"), tet_mesh("red")]
    data["lights"] = data["lights"] * 2
    limits = Limits(max_objects=4, max_triangles=7, max_lights=1, max_materials=3)
    data["objects"][0] = {"type": "nonsense"}  # not reported: the scene is refused before parsing
    assert errors_of(data, limits=limits) == [
        ("objects", "5 objects exceed the limit 4 (LUCENT_MAX_OBJECTS)"),
        ("objects", "8 triangles over all meshes exceed the limit 7 (LUCENT_MAX_TRIANGLES)"),
        ("lights", "2 lights exceed the limit 1 (LUCENT_MAX_LIGHTS)"),
        ("materials", "4 materials exceed the limit 3 (LUCENT_MAX_MATERIALS)"),
    ]


def test_count_limits_from_environment(monkeypatch):
    monkeypatch.setenv("LUCENT_MAX_OBJECTS", "1")
    assert errors_of(scene_dict()) == [
        ("objects", "2 objects exceed the limit 1 (LUCENT_MAX_OBJECTS)")
    ]


# --- Meshes ---------------------------------------------------------------------------------------


def test_closed_mesh_loads_and_gives_arrays():
    scene = load_scene(scene_dict(objects=[tet_mesh("glass"), tet_mesh("wax")]))
    mesh = scene.objects[0]
    assert isinstance(mesh, Mesh)
    vertices, triangles = mesh.arrays()
    assert vertices.dtype == np.float64 and vertices.shape == (4, 3)
    assert triangles.dtype == np.int64 and triangles.shape == (4, 3)
    np.testing.assert_array_equal(triangles, TET_TRIANGLES)
    assert mesh.arrays()[0] is vertices  # built once
    assert not vertices.flags.writeable  # the cache cannot be changed behind the model's back
    assert mesh.dropped_degenerate == 0 and mesh.num_triangles == 4


def test_open_mesh_is_fine_for_opaque_materials():
    load_scene(scene_dict(objects=[tet_mesh("red", triangles=TET_TRIANGLES[:3])]))


@pytest.mark.parametrize("material", ["glass", "wax"])
def test_open_mesh_rejected_for_media(material):
    kind = {"glass": "dielectric", "wax": "translucent"}[material]
    data = scene_dict(objects=[tet_mesh("red"), tet_mesh(material, triangles=TET_TRIANGLES[:3])])
    assert errors_of(data) == [
        ("objects[1]", f"a {kind} mesh must be closed (edge (1, 2) is used by 1 triangle)")
    ]


def test_mesh_used_three_times_on_an_edge_is_not_closed():
    triangles = TET_TRIANGLES + [[0, 1, 3]]
    assert errors_of(scene_dict(objects=[tet_mesh(triangles=triangles)])) == [
        ("objects[0]", "a dielectric mesh must be closed (edge (0, 1) is used by 3 triangles)")
    ]


def test_inconsistently_wound_mesh_is_rejected():
    triangles = TET_TRIANGLES[:3] + [[1, 3, 2]]  # last face flipped
    assert errors_of(scene_dict(objects=[tet_mesh(triangles=triangles)])) == [
        (
            "objects[0]",
            "a dielectric mesh must be consistently oriented (edge (1, 2) runs the same way in "
            "both of its triangles: flip one so that neighbours agree)",
        )
    ]


def test_mesh_index_out_of_range():
    data = scene_dict(objects=[tet_mesh("red", triangles=[[0, 1, 2], [0, 4, 2]])])
    assert errors_of(data) == [
        ("objects[0].triangles[1]", "vertex index 4 out of range (the mesh has 4 vertices)")
    ]


def test_inline_degenerate_triangles_are_errors_naming_the_first_few():
    vertices = TET_VERTICES + [[2, 0, 0]]  # collinear with vertices 0 and 1
    triangles = [[0, 1, 2]] * 5 + [[0, 1, 4], [0, 0, 2]] + [[0, 1, 1]] * 6
    data = scene_dict(
        objects=[
            {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "red"},
            tet_mesh("red", vertices=vertices, triangles=triangles),
        ]
    )
    assert errors_of(data) == [
        ("objects[1].triangles[5]", "degenerate triangle (zero area)"),
        ("objects[1].triangles[6]", "degenerate triangle (zero area)"),
        ("objects[1].triangles[7]", "degenerate triangle (zero area)"),
        ("objects[1].triangles[8]", "degenerate triangle (zero area)"),
        ("objects[1].triangles[9]", "degenerate triangle (zero area)"),
        ("objects[1].triangles", "3 more degenerate triangles"),
    ]


def test_degenerate_test_is_scale_free():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 1e-14, 0], [0.5, 0.5, 0]])
    triangles = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 4]])
    np.testing.assert_array_equal(degenerate_triangles(vertices, triangles), [False, True, True])
    np.testing.assert_array_equal(
        degenerate_triangles(vertices * 1e-6, triangles), [False, True, True]
    )
    np.testing.assert_array_equal(
        degenerate_triangles(vertices * 1e6, triangles), [False, True, True]
    )


def test_degenerate_test_is_scale_free_up_to_where_squares_overflow():
    # 1e150 and 1e-150: the products of the old test overflowed (inf <= inf: "degenerate") or
    # underflowed (0 <= 0) there; an edge of 1e200 overflows where the renderer squares it.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 1e-14, 0], [0.5, 0.5, 0]])
    triangles = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 4]])
    for scale in (1e150, 1e-150):
        degenerate, overflow = triangle_faults(vertices * scale, triangles)
        np.testing.assert_array_equal(degenerate, [False, True, True])
        np.testing.assert_array_equal(overflow, [False, False, False])
    degenerate, overflow = triangle_faults(vertices * 1e200, triangles)
    np.testing.assert_array_equal(degenerate, [False, False, False])
    np.testing.assert_array_equal(overflow, [True, True, True])


# --- Numbers too large to compute with ------------------------------------------------------------

OVERFLOW = "overflows: its squared length exceeds the largest float (about 1.8e308)"


@pytest.mark.parametrize(
    "change, path",
    [
        # The issue's case: each coordinate finite, their differences' squares not
        pytest.param(_set(("camera", "position"), [1e308, 1e308, 1e308]), "camera",
                     id="camera at 1e308"),
        pytest.param(_set(("camera", "position"), [1e308, 0, 0]), "camera",
                     id="look_at - position is -inf"),
        pytest.param(_set(("camera", "up"), [0, 1e200, 0]), "camera.up", id="up"),
        pytest.param(_set(("objects", 1, "edge1"), [1e200, 0, 0]), "objects[1]", id="quad edge"),
        pytest.param(_set(("objects", 1), {"type": "quad", "origin": [0, 0, 0],
                                           "edge1": [1e100, 0, 0], "edge2": [0, 0, 1e100],
                                           "material": "red"}),
                     "objects[1]", id="quad normal"),
        pytest.param(_set(("lights", 0), {"type": "directional", "direction": [1e200, -1, 0],
                                          "irradiance": [1, 1, 1]}),
                     "lights[0].direction", id="light direction"),
        pytest.param(_set(("objects", 1), {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1],
                                           "rotate": {"axis": [0, 1e200, 0], "angle": 10},
                                           "material": "red"}),
                     "objects[1].rotate.axis", id="rotation axis"),
    ],
)
def test_overflow_is_reported_as_overflow(change, path):
    """Finite numbers whose squares overflow are said to overflow, not to be parallel or
    degenerate (what the infinite cross products looked like)."""
    data = scene_dict()
    change(data)
    ((where, message),) = errors_of(data)
    assert where == path
    assert OVERFLOW in message
    assert "parallel" not in message and "degenerate" not in message


def test_mesh_triangles_that_overflow_are_named():
    vertices = [[0, 0, 0], [1e200, 0, 0], [0, 1e200, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]]
    data = scene_dict(objects=[tet_mesh("red", vertices=vertices,
                                        triangles=[[3, 4, 5], [0, 1, 2]])])
    ((where, message),) = errors_of(data)
    assert where == "objects[0].triangles[1]"
    assert message.startswith(f"an edge of the triangle {OVERFLOW}")


def test_vertex_indices_beyond_int64_are_errors_not_overflow():
    """An index past int64 (the kernels' integers) is refused by the schema, before numpy."""
    for index in (2**63, 2**64, 10**30):
        data = scene_dict(objects=[tet_mesh("red", triangles=[[0, 1, 2], [0, 1, index]])])
        assert errors_of(data) == [
            ("objects[0].triangles[1][2]", f"must be <= {2**63 - 1}")
        ]
    data = scene_dict(objects=[tet_mesh("red", triangles=[[0, 1, 2], [0, 1, 2**63 - 1]])])
    assert errors_of(data) == [
        ("objects[0].triangles[1]",
         f"vertex index {2**63 - 1} out of range (the mesh has 4 vertices)")
    ]


def test_large_closed_mesh_validates_fast():
    # 200k triangles: inline lists, pydantic, numpy checks (about 0.3 s; not asserted).
    vertices, triangles = torus(500, 200)
    assert triangles.shape == (200_000, 3)
    data = scene_dict(objects=[tet_mesh("wax", vertices.tolist(), triangles.tolist())])
    mesh = load_scene(data).objects[0]
    np.testing.assert_array_equal(mesh.arrays()[1], triangles)

    # One triangle removed: the first of the three edges it leaves open is named.
    removed = triangles[123_457].tolist()
    edge = min(tuple(sorted((removed[k], removed[(k + 1) % 3]))) for k in range(3))
    data["objects"][0]["triangles"].pop(123_457)
    assert errors_of(data) == [
        ("objects[0]", f"a translucent mesh must be closed (edge {edge} is used by 1 triangle)")
    ]


def test_find_open_edge_on_closed_meshes():
    assert find_open_edge(np.array(TET_TRIANGLES)) is None
    assert find_open_edge(torus(7, 5)[1]) is None


# --- Mesh files -----------------------------------------------------------------------------------


@pytest.fixture
def fake_meshio(monkeypatch):
    """A stand-in for renderer.geometry.meshio's parsers that records the files it is given (by
    the resolved path load_scene names them with); ``put(tmp_path / "a.obj", (v, t))`` writes a
    placeholder file and says what parsing it gives."""
    calls: list[Path] = []
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def parse(data, *, name):
        calls.append(Path(name))
        return meshes[Path(name).name]

    def put(path: Path, arrays):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("v 0 0 0\n")
        meshes[path.name] = arrays

    def parse_mesh(data, kind, *, name):
        return (*parse(data, name=name), None, None)  # no texture coordinates, no normals

    module = types.ModuleType("renderer.geometry.meshio")
    module.parse_obj = module.parse_ply = parse
    module.parse_mesh = parse_mesh
    monkeypatch.setitem(sys.modules, "renderer.geometry.meshio", module)
    return put, calls


def test_mesh_file_is_loaded_with_allow_paths(fake_meshio, tmp_path):
    put, calls = fake_meshio
    vertices = np.array(TET_VERTICES + [[2, 0, 0]], dtype=np.float64)
    triangles = np.array(TET_TRIANGLES + [[0, 1, 4], [0, 0, 3]], dtype=np.int64)  # 2 degenerate
    put(tmp_path / "models" / "tet.obj", (vertices, triangles))
    data = scene_dict(objects=[{"type": "mesh", "material": "glass", "path": "models/tet.obj"}])

    scene = load_scene(data, allow_paths=True, base_dir=tmp_path)
    assert calls == [(tmp_path / "models" / "tet.obj").resolve()]
    mesh = scene.objects[0]
    assert mesh.path is None and mesh.source_path == (tmp_path / "models" / "tet.obj").resolve()
    assert mesh.dropped_degenerate == 2 and mesh.num_triangles == 4
    v, t = mesh.arrays()
    np.testing.assert_array_equal(t, TET_TRIANGLES)
    np.testing.assert_array_equal(v, vertices)

    # The loaded scene serializes inline, and the HTTP API (no paths) accepts that.
    dumped = json.loads(scene.model_dump_json())
    assert dumped["objects"][0]["triangles"] == TET_TRIANGLES and "path" not in dumped["objects"][0]
    again = load_scene(dumped)
    np.testing.assert_array_equal(again.objects[0].arrays()[1], TET_TRIANGLES)


def test_mesh_file_errors(fake_meshio, tmp_path):
    put, _ = fake_meshio
    put(tmp_path / "open.obj", (np.array(TET_VERTICES, float), np.array(TET_TRIANGLES[1:])))
    put(tmp_path / "bad.obj", (np.array(TET_VERTICES, float), np.array([[0, 1, 2], [0, 1, 9]])))
    data = scene_dict(
        objects=[
            {"type": "mesh", "material": "glass", "path": "missing.obj"},
            {"type": "mesh", "material": "glass", "path": "open.obj"},
            {"type": "mesh", "material": "red", "path": "bad.obj"},
        ]
    )
    errors = errors_of(data, allow_paths=True, base_dir=tmp_path)
    assert errors == [
        (
            "objects[0].path",
            f"cannot read {str(tmp_path / 'missing.obj')!r}: No such file or directory",
        ),
        ("objects[1]", "a dielectric mesh must be closed (edge (0, 1) is used by 1 triangle)"),
        ("objects[2].path", "triangle 1: vertex index 9 out of range (the mesh has 4 vertices)"),
    ]


def test_file_mesh_triangles_count_towards_the_limit(fake_meshio, tmp_path):
    put, _ = fake_meshio
    put(tmp_path / "tet.obj", (np.array(TET_VERTICES, float), np.array(TET_TRIANGLES)))
    data = scene_dict(
        objects=[{"type": "mesh", "material": "glass", "path": "tet.obj"}, tet_mesh("glass")]
    )
    assert errors_of(data, allow_paths=True, base_dir=tmp_path, limits=Limits(max_triangles=7)) == [
        ("objects", "8 triangles over all meshes exceed the limit 7 (LUCENT_MAX_TRIANGLES)")
    ]


def test_scene_file_with_obj_mesh(tmp_path):
    pytest.importorskip("renderer.geometry.meshio")
    lines = [f"v {x} {y} {z}" for x, y, z in TET_VERTICES]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in TET_TRIANGLES]
    (tmp_path / "tet.obj").write_text("\n".join(lines) + "\n")
    data = scene_dict(objects=[{"type": "mesh", "material": "wax", "path": "tet.obj"}])
    (tmp_path / "scene.json").write_text(json.dumps(data))
    mesh = load_scene_file(tmp_path / "scene.json").objects[0]
    vertices, triangles = mesh.arrays()
    np.testing.assert_allclose(vertices, TET_VERTICES)
    assert triangles.shape == (4, 3) and mesh.path is None


# --- Scene files ----------------------------------------------------------------------------------


def test_scene_file_invalid_json(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text('{\n  "film": {"width": 16 "height": 12}\n}\n')
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    assert info.value.errors == [
        ("(file)", "invalid JSON at line 2, column 24: Expecting ',' delimiter")
    ]


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity"])
def test_scene_file_rejects_nan_and_infinity(tmp_path, token):
    text = json.dumps(scene_dict()).replace('"radius": 0.5', f'"radius": {token}')
    assert token in text
    path = tmp_path / "scene.json"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    assert info.value.errors == [
        ("objects[0].radius", f"must be a finite number ({token} is not valid JSON)")
    ]


def test_scene_file_missing(tmp_path):
    with pytest.raises(SceneError) as info:
        load_scene_file(tmp_path / "nope.json")
    [(path, message)] = info.value.errors
    assert path == "(file)" and message.startswith("cannot read ") and "No such file" in message


def test_scene_file_top_level_array(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text("[1, 2]")
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    assert info.value.errors == [("(root)", "a scene must be a JSON object")]


# --- Models used directly -------------------------------------------------------------------------


def test_models_construct_with_defaults():
    camera = Camera(position=(0, 0, 1), look_at=(0, 0, 0))
    assert camera.up == (0, 1, 0)
    box = Box(min=(0, 0, 0), max=(1, 1, 1), material="m")
    assert box.type == "box" and box.rotate is None and box.translate == (0, 0, 0)
    with pytest.raises(ValueError, match="degenerate quad"):
        Quad(origin=(0, 0, 0), edge1=(1, 0, 0), edge2=(2, 0, 0), material="m")


def test_a_material_name_with_a_lone_surrogate_is_an_error():
    """A str field refuses "\\ud800" (no Unicode text); a dict key was not checked, so the name
    reached replies and Redis, which cannot encode it."""
    data = scene_dict()
    data["materials"]["a\ud800"] = data["materials"].pop("red")
    assert errors_of(data) == [
        ("materials", "the material name 'a\\\\ud800' is not Unicode text (it holds a lone "
         "UTF-16 surrogate)")
    ]
