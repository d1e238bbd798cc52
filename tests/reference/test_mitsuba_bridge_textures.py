"""The Mitsuba 3 bridge's textures, texture coordinates and shading normals (scene format v1.1):
``bitmap`` and ``checkerboard`` on a quad, a sphere and a mesh with ``uvs``, and a smooth-shaded
mesh, each rendered by Lucent and by Mitsuba 3 from the same scene. The stored-reference agreement
(error within Mitsuba's own at equal spp) is tests/renderer/integrators/test_mitsuba_agreement.py
(``tex_bitmap_quad``, ``tex_checker_quad``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from renderer.geometry.meshgen import uv_sphere  # noqa: E402
from renderer.mitsuba_bridge import default_variant, render_mitsuba  # noqa: E402
from renderer.render import render  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

pytestmark = pytest.mark.mitsuba

DATA = Path(__file__).resolve().parents[1] / "data"
VARIANT = default_variant()


def both(scene: dict, spp: int, base_dir: Path = DATA) -> tuple[np.ndarray, np.ndarray]:
    scene = json.loads(json.dumps(scene))
    scene["render"]["spp"] = spp
    ours = render(load_scene(scene, allow_paths=True, base_dir=base_dir))
    theirs = render_mitsuba(scene, spp=spp, seed=1, variant=VARIANT, base_dir=base_dir)
    return ours.astype(np.float64), theirs.astype(np.float64)


@pytest.mark.parametrize("offset", [[0.0, 0.0], [0.3, 0.6]])
def test_a_bitmap_quad_is_the_same_image(offset):
    """The test bitmap (a gradient, a dark band near its bottom, a bright mark top-left) on a
    quad facing the camera, seen under a white background at max_depth 1 (the albedo itself):
    pixel by pixel the same in both, to the noise of the pixel footprint (a flipped or shifted
    u or v differs by ~0.2 on average)."""
    scene = {
        "camera": {"position": [0.5, 0.5, 1.9], "look_at": [0.5, 0.5, 0], "fov": 30},
        "film": {"width": 32, "height": 32},
        "render": {"spp": 64, "max_depth": 1, "seed": 1},
        "background": [1, 1, 1],
        "materials": {"m": {"type": "diffuse", "albedo": {
            "type": "bitmap", "image": "texture_16x16.png", "scale": [1.5, 1], "offset": offset}}},
        "objects": [{"type": "quad", "origin": [0, 0, 0], "edge1": [1, 0, 0],
                     "edge2": [0, 1, 0], "material": "m"}],
    }
    ours, theirs = both(scene, 256)
    assert np.abs(ours - theirs).mean() < 0.01, np.abs(ours - theirs).mean()


def smooth_sphere_scene(material: dict, uvs: bool) -> dict:
    vertices, triangles, normals, uv = uv_sphere(24, 16)
    mesh = {"type": "mesh", "vertices": vertices.tolist(), "triangles": triangles.tolist(),
            "normals": normals.tolist(), "material": "m"}
    if uvs:
        mesh["uvs"] = uv.tolist()
    return {
        "camera": {"position": [0, 0.8, 4], "look_at": [0, 0, 0], "fov": 32},
        "film": {"width": 32, "height": 32},
        "render": {"spp": 256, "max_depth": -1, "seed": 1},
        "background": [0.6, 0.7, 0.8],
        "materials": {"m": material},
        "lights": [{"type": "point", "position": [2, 3, 3], "intensity": [15, 15, 15]}],
        "objects": [mesh],
    }


@pytest.mark.parametrize("material, uvs", [
    ({"type": "diffuse", "albedo": [0.8, 0.6, 0.4]}, False),
    ({"type": "diffuse", "albedo": {"type": "checkerboard", "color0": [0.9, 0.2, 0.1],
                                    "color1": [0.8, 0.8, 0.8], "scale": [8, 4]}}, True),
    ({"type": "conductor", "preset": "Cu", "roughness": 0.3}, False),
], ids=["diffuse", "checkerboard", "rough-copper"])
def test_a_smooth_shaded_textured_mesh_renders_as_mitsubas(material, uvs):
    """A sphere mesh (24 × 16 quads) with its radial normals (and, textured, the sphere's uvs):
    Mitsuba interpolates the same normals and uvs. The channel means over the sphere agree to
    1 % (measured +0.3 %, +0.3 %, +0.4 %: Lucent's folding keeps the light Mitsuba loses where
    the shading and geometric normals disagree about a direction, near the silhouette;
    renderer/materials/shading.py)."""
    ours, theirs = both(smooth_sphere_scene(material, uvs), 512)
    window = (slice(6, 26), slice(6, 26))
    np.testing.assert_allclose(ours[window].mean(axis=(0, 1)), theirs[window].mean(axis=(0, 1)),
                               rtol=0.01)


@pytest.mark.parametrize("material", [{"type": "diffuse", "albedo": [0.8, 0.6, 0.4]},
                                      {"type": "conductor", "preset": "Cu", "roughness": 0.3}],
                         ids=["diffuse", "rough-copper"])
def test_shading_is_smooth_as_in_mitsuba(material):
    """Direct light of a point light alone (max_depth 1, no background: no noise but the pixel
    jitter): Lucent's smooth-shaded sphere mesh is Mitsuba's pixel by pixel, several times
    closer than the faceted mesh is (measured: mean |difference| 0.0005 against 0.0045 faceted
    for the diffuse sphere, 0.0014 against 0.016 for the rough copper)."""
    scene = smooth_sphere_scene(material, False)
    scene["background"], scene["render"]["max_depth"] = [0, 0, 0], 1
    ours, theirs = both(scene, 64)
    flat = json.loads(json.dumps(scene))
    del flat["objects"][0]["normals"]
    faceted = render(load_scene(flat)).astype(np.float64)
    window = (slice(6, 26), slice(6, 26))
    smooth, facets = np.abs(ours - theirs)[window].mean(), np.abs(faceted - theirs)[window].mean()
    assert smooth < 0.25 * facets, (smooth, facets)


def test_a_textured_sphere_has_the_meshs_parametrization():
    """A checkerboard on the analytic sphere and on the sphere mesh with the same (u, v)
    (meshgen.uv_sphere): Mitsuba's sphere (turned by the bridge into the scene format's
    parametrization) and Lucent's agree on the sphere's pixels."""
    checker = {"type": "diffuse", "albedo": {"type": "checkerboard", "color0": [0.9, 0.2, 0.1],
                                             "color1": [0.1, 0.3, 0.9], "scale": [6, 3]}}
    scene = smooth_sphere_scene(checker, True)
    scene["objects"] = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]
    ours, theirs = both(scene, 256)
    window = (slice(6, 26), slice(6, 26))
    assert np.abs(ours - theirs)[window].mean() < 0.03, np.abs(ours - theirs)[window].mean()


@pytest.mark.parametrize("roughness", [0.0, 0.2])
def test_a_smooth_shaded_glass_mesh_renders_as_mitsubas(roughness):
    """A 320-triangle icosphere of glass (smooth, and rough at α 0.2) with its vertex normals,
    in front of a checkerboard: Mitsuba 3 shades a dielectric about the interpolated normal too
    (renderer/materials/shading.py, ``_refracted_about`` and ``_two_sided_terms``). Channel means
    over the sphere's window within 1 % (measured 0.4 % smooth, 0.01 % rough, 256 spp); smooth:
    the mean per-pixel difference below 0.04 (measured 0.019; the flat-shaded mesh differs from
    Mitsuba's smooth one by 0.204)."""
    from tests.renderer.integrators.test_shading_refraction import glass_scene

    material = {"type": "dielectric", "ior": 1.5, "roughness": roughness}
    ours, theirs = both(glass_scene("smooth", material), 256)
    window = np.s_[6:26, 6:26]
    np.testing.assert_allclose(ours[window].mean(axis=(0, 1)), theirs[window].mean(axis=(0, 1)),
                               rtol=0.01)
    if roughness == 0.0:
        assert np.abs(ours - theirs)[window].mean() < 0.04, np.abs(ours - theirs)[window].mean()
