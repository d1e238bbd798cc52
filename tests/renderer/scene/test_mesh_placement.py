"""A mesh's placement (scene format v1.1, "Textures, UVs and shading normals": Placement): scale,
then rotate, then translate, about the world origin, as a box is placed."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from renderer.render import render_buffer
from renderer.scene import SceneError, load_scene, load_scene_file
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[3]

# The unit cube [0, 1]³ as 12 outward-facing triangles
CUBE_V = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
CUBE_T = [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
          [2, 3, 7], [2, 7, 6], [1, 2, 6], [1, 6, 5], [0, 4, 7], [0, 7, 3]]
ROTATE = {"axis": [1, 2, 0.5], "angle": 37.0}


def scene_with(obj: dict) -> dict:
    return {
        "camera": {"position": [0, 1, 8], "look_at": [0.5, 0.5, 0.5], "fov": 35},
        "film": {"width": 24, "height": 18},
        "render": {"spp": 16, "max_depth": 4, "seed": 3},
        "background": [0.6, 0.7, 0.8],
        "materials": {"m": {"type": "diffuse", "albedo": [0.7, 0.5, 0.3]}},
        "lights": [{"type": "point", "position": [3, 5, 6], "intensity": [40, 40, 40]}],
        "objects": [obj],
    }


def test_a_placed_cube_is_the_box_placed_the_same_way():
    """The unit cube as a mesh, scaled by (2, 1, 0.5), rotated and translated, covers the box
    [0, 2]×[0, 1]×[0, 0.5] rotated and translated alike: same image (the box's quads and the
    mesh's triangles differ only in how the faces are cut)."""
    mesh = {"type": "mesh", "vertices": CUBE_V, "triangles": CUBE_T, "material": "m",
            "scale": [2, 1, 0.5], "rotate": ROTATE, "translate": [-1, 0.2, 0.3]}
    box = {"type": "box", "min": [0, 0, 0], "max": [2, 1, 0.5], "material": "m",
           "rotate": ROTATE, "translate": [-1, 0.2, 0.3]}
    a = render_buffer(load_scene(scene_with(mesh)))
    b = render_buffer(load_scene(scene_with(box)))
    img_a, img_b = a.sum / a.count[..., None], b.sum / b.count[..., None]
    assert np.abs(img_a - img_b).max() < 1e-6


def test_world_vertices_follow_scale_rotate_translate():
    mesh = {"type": "mesh", "vertices": CUBE_V, "triangles": CUBE_T, "material": "m",
            "scale": 3.0, "rotate": {"axis": [0, 0, 1], "angle": 90}, "translate": [1, 2, 3]}
    scene = load_scene(scene_with(mesh))
    world, _ = scene.objects[0].arrays()
    model, _ = scene.objects[0].model_arrays()
    # (1, 0, 0) scaled to (3, 0, 0), turned to (0, 3, 0), moved to (1, 5, 3)
    np.testing.assert_allclose(world[1], [1, 5, 3], atol=1e-12)
    np.testing.assert_array_equal(model[1], [1, 0, 0])
    assert world.shape == model.shape


def test_a_mesh_file_is_placed_without_editing_it():
    """The torus example's PLY, scaled and moved: the compiled triangles are the file's, placed;
    a dumped scene keeps the file's coordinates and the placement, so it loads to the same."""
    data = json.loads((ROOT / "examples" / "translucent_torus.json").read_text())
    index = next(i for i, o in enumerate(data["objects"]) if o["type"] == "mesh")
    placed = copy.deepcopy(data)
    placed["objects"][index].update(scale=0.5, translate=[0.25, 0.0, -0.5])
    plain = load_scene_file(ROOT / "examples" / "translucent_torus.json")
    original, _ = plain.objects[index].arrays()
    moved = load_scene(placed, allow_paths=True, base_dir=ROOT / "examples")
    world, _ = moved.objects[index].arrays()
    np.testing.assert_allclose(world, original * 0.5 + [0.25, 0.0, -0.5])
    again = load_scene(json.loads(moved.model_dump_json()))
    np.testing.assert_allclose(again.objects[index].arrays()[0], world)
    assert compile_scene(moved).info["triangles"] == compile_scene(plain).info["triangles"]


@pytest.mark.parametrize(("field", "value", "message"), [
    ("scale", 0, "must be a number > 0, or a list of 3 numbers > 0 (one per axis)"),
    ("scale", [1, -1, 1], "must be a number > 0, or a list of 3 numbers > 0 (one per axis)"),
    ("rotate", {"axis": [0, 0, 0], "angle": 3}, None),
    ("translate", [0, 0], None),
])
def test_bad_placement_is_named(field, value, message):
    mesh = {"type": "mesh", "vertices": CUBE_V, "triangles": CUBE_T, "material": "m",
            field: value}
    with pytest.raises(SceneError) as err:
        load_scene(scene_with(mesh))
    paths = [p for p, _ in err.value.errors]
    assert any(p.startswith(f"objects[0].{field}") for p in paths), err.value.errors
    if message is not None:
        assert (f"objects[0].{field}", message) in err.value.errors


def test_a_scale_that_overflows_is_named():
    mesh = {"type": "mesh", "vertices": CUBE_V, "triangles": CUBE_T, "material": "m",
            "scale": 1e308}
    with pytest.raises(SceneError) as err:
        load_scene(scene_with(mesh))
    assert any(p.startswith("objects[0]") and "overflow" in m for p, m in err.value.errors), \
        err.value.errors
