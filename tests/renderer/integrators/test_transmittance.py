"""Shadow-ray transmittance through single-scatter and index-matched media (renderer/integrators/
path.py): against Beer–Lambert on boxes of known size, and the flat scenes' one-pass sum against
the crossing-by-crossing loop it replaces there."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import renderer.scene.compile as compile_module
from renderer.geometry.bvh import traversal_stack
from renderer.integrators.shadow import (
    flat_transmittance,
    transmittance,
    transmittance_by_crossing,
)
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
SF = 0.3  # surface_fraction: the share of light the surface reflects; 1 − SF goes in


def two_boxes(density, method: str = "single_scatter", shape: str = "box") -> dict:
    """Unit boxes at x ∈ [0, 1] and [2, 3.5] (y, z ∈ [0, 1]) and a distant floor; with ``shape``
    "sphere", the spheres those boxes' x extents are diameters of, centred on y = z = 0.5 (a ray
    along x at y = z = 0.5 crosses the same lengths of medium)."""
    material = {"type": "translucent", "method": method, "ior": 1.0, "density": density,
                "g": 0.0, "albedo": [0.8, 0.8, 0.8]}
    if method == "single_scatter":
        material["surface_fraction"] = SF
    return {
        "camera": {"position": [0, 0, 10], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
        "film": {"width": 8, "height": 8},
        "render": {"spp": 1, "max_depth": 8, "seed": 1},
        "materials": {"m": material, "floor": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
                      "light": {"type": "diffuse", "albedo": [0, 0, 0]}},
        "objects": [
            *([{"type": "box", "min": [0, 0, 0], "max": [1, 1, 1], "material": "m"},
               {"type": "box", "min": [2, 0, 0], "max": [3.5, 1, 1], "material": "m"}]
              if shape == "box" else
              [{"type": "sphere", "center": [0.5, 0.5, 0.5], "radius": 0.5, "material": "m"},
               {"type": "sphere", "center": [2.75, 0.5, 0.5], "radius": 0.75, "material": "m"}]),
            {"type": "quad", "origin": [-9, -5, 9], "edge1": [18, 0, 0], "edge2": [0, 0, -18],
             "material": "floor"},
            {"type": "quad", "origin": [0, 5, 0], "edge1": [1, 0, 0], "edge2": [0, 0, 1],
             "material": "light", "emission": [1, 1, 1]},
        ],
    }


def compiled(data: dict, flat: bool, monkeypatch):
    if not flat:
        monkeypatch.setattr(compile_module, "FLAT_MAX", 0)
    cs = compile_scene(load_scene(data))
    monkeypatch.undo()
    assert cs.info["flat"] == flat
    return cs


@pytest.mark.parametrize("shape", ["box", "sphere"])
@pytest.mark.parametrize("flat", [True, False])
@pytest.mark.parametrize("method", ["single_scatter", "volumetric"])
@pytest.mark.parametrize("sigma", [0.7, (0.7, 2.0, 0.1)], ids=["grey", "chromatic"])
def test_beer_lambert_through_two_boxes(flat, method, shape, sigma, monkeypatch):
    # A ray along +x at y = z = 0.5 crosses 1 + 1.5 of medium: exp(−σ·2.5), times (1 − SF) for
    # each single-scatter surface it enters; from inside the first box only the rest counts.
    # Spheres of those diameters give the same lengths (flat: both roots from one pass). A
    # chromatic medium: each channel at its own σt.
    cs = compiled(two_boxes(sigma if isinstance(sigma, float) else list(sigma), method, shape),
                  flat, monkeypatch)
    sigma = np.broadcast_to(np.asarray(sigma), (3,))
    S = cs.arrays
    entry = (1.0 - SF) if method == "single_scatter" else 1.0
    stack = traversal_stack(cs.stack_size)
    d = (1.0, 0.0, 0.0)
    cases = [
        ((-1.0, 0.5, 0.5), 5.0, -1, entry**2 * np.exp(-sigma * 2.5)),
        ((-1.0, 0.5, 0.5), 3.75, -1, entry**2 * np.exp(-sigma * 1.75)),  # ends in box 2
        ((-1.0, 0.5, 0.5), 2.5, -1, entry * np.exp(-sigma * 1.0)),  # between the boxes
        ((-1.0, 0.5, 0.5), 1.5, -1, entry * np.exp(-sigma * 0.5)),  # ends in box 1
        ((0.25, 0.5, 0.5), 5.0, 0, entry * np.exp(-sigma * (0.75 + 1.5))),  # from inside
        ((0.25, 0.5, 0.5), 0.5, 0, np.exp(-sigma * 0.5)),  # all inside
        # to a light at infinity (a directional light, the background)
        ((-1.0, 0.5, 0.5), math.inf, -1, entry**2 * np.exp(-sigma * 2.5)),
        ((0.25, 0.5, 0.5), math.inf, 0, entry * np.exp(-sigma * 2.25)),
        ((2.5, 0.5, 0.5), math.inf, 0, np.exp(-sigma * 1.0)),
    ]
    for o, t_max, medium, expected in cases:
        # 1e-8: the crossing loop goes on 1e-9 (SPAWN_EPSILON) past each surface
        assert transmittance(S, o, d, t_max, medium, stack) == pytest.approx(tuple(expected),
                                                                            rel=1e-8)
    # The floor blocks; a ray past the boxes' side sees nothing
    assert transmittance(S, (0.5, 0.5, 0.5), (0.0, -1.0, 0.0), 20.0, 0, stack) == (0.0,) * 3
    assert transmittance(S, (-1.0, 2.0, 0.5), d, 5.0, -1, stack) == (1.0,) * 3
    # A ray that starts and ends inside one object crosses nothing
    assert transmittance(S, (2.5, 0.5, 0.5), d, 0.5, 0, stack) == pytest.approx(
        tuple(np.exp(-sigma * 0.5)), rel=1e-12)


def seed_boxes_with_spheres() -> dict:
    """The high-density seed boxes with four spheres among them: single-scatter, index-matched
    volumetric, and an opaque one a shadow ray may start inside (22 primitives: still flat)."""
    data = json.loads((EXAMPLES / "seed_paper_boxes_high_density.json").read_text())
    data["materials"]["jelly"] = {"type": "translucent", "method": "volumetric", "ior": 1.0,
                                  "density": 3.0, "g": 0.2, "albedo": [0.9, 0.8, 0.7]}
    data["objects"] += [
        {"type": "sphere", "center": [0.3, 0.3, -0.2], "radius": 0.25, "material": "blue_box"},
        {"type": "sphere", "center": [-0.5, 0.5, 0.4], "radius": 0.3, "material": "amber_box"},
        {"type": "sphere", "center": [0.0, -0.2, 0.5], "radius": 0.2, "material": "jelly"},
        {"type": "sphere", "center": [0.6, 0.6, 0.5], "radius": 0.2, "material": "white"},
    ]
    return data


@pytest.mark.parametrize("scene", ["seed_paper_boxes_high_density", "seed_paper_boxes_low_density",
                                   "with_spheres"])
def test_one_pass_sum_matches_the_crossing_loop(scene, rng):
    # The seed boxes (flat: 18 quads), and with four spheres among them: shadow rays from above
    # the boxes (vacuum) and from inside the blue box, in every direction, of random length: the
    # one-pass optical depth gives the loop's transmittance to rounding (the loop restarts 1e-9
    # past each surface).
    data = (seed_boxes_with_spheres() if scene == "with_spheres"
            else json.loads((EXAMPLES / f"{scene}.json").read_text()))
    cs = compile_scene(load_scene(data))
    S = cs.arrays
    assert cs.info["flat"] and (S.prim_kind[0] == 0) == (scene == "with_spheres")
    blue = list(data["materials"]).index("blue_box")
    faces = S.prim_geo[(S.prim_material == blue) & (S.prim_kind != 0)]
    centre = (faces[:, 0:3] + 0.5 * faces[:, 3:6] + 0.5 * faces[:, 6:9]).mean(axis=0)
    stack = traversal_stack(cs.stack_size)
    n = 3000
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_max = rng.uniform(0.05, 3.0, n)
    above = np.column_stack([rng.uniform(-0.9, 0.9, n), rng.uniform(0.25, 0.95, n),
                             rng.uniform(-0.9, 0.9, n)])
    inside = centre + rng.uniform(-0.2, 0.2, (n, 3)) * [1.0, 2.5, 1.0]
    spheres = [(S.prim_geo[k, :3], S.prim_geo[k, 3], S.prim_material[k])
               for k in np.flatnonzero(S.prim_kind == 0)]
    passable = {i for i, m in enumerate(data["materials"].values())
                if m["type"] == "translucent"}
    got, want = [], []
    for origins, outside in ((above, -1), (inside, blue)):
        for o, d, tm in zip(origins, dirs, t_max, strict=True):
            # The medium at o: a sphere's when o is in one (vacuum in the opaque sphere)
            medium = outside
            for c, r, mat in spheres:
                if np.linalg.norm(o - c) < r:
                    medium = mat if mat in passable else -1
            o, d = tuple(o), tuple(d)
            got.append(flat_transmittance(S, o, d, tm, medium, stack[2]))
            want.append(transmittance_by_crossing(S, o, d, tm, medium, stack))
    got, want = np.array(got), np.array(want)
    # The loop's steps past each surface (1e-9 of the primitive's scale) shorten the path in a
    # medium of σt = 30 by a few 1e-9 to 1e-8: its optical depth, the relative difference of the
    # two, by ~1e-7 (one ray of 6,000 through two spheres and a box: 1.3e-6)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-300)
    assert np.array_equal(got == 0, want == 0)
    # Every case is exercised: blocked, free, and partly through a box
    assert (want == 0).mean() > 0.1 and (want == 1).mean() > 0.05
    assert ((want > 0) & (want < 1)).mean() > 0.1
