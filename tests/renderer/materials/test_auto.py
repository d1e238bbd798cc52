"""``method: "auto"``: the choice, its reason, and that the chosen model is what gets rendered."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from renderer.materials.auto import (
    BIAS_FLOOR,
    DEFAULT_TARGET,
    auto_choice,
    choose_method,
    scene_regimes,
)
from renderer.render import render
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[3]


def wax_scene(method: str, target=None, **material) -> dict:
    data = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    data["film"] = {"width": 24, "height": 18}
    data["render"]["spp"] = 8
    if target is not None:
        data["render"]["target_error"] = target
    data["materials"]["wax"].update(method=method, **material)
    return data


def test_default_target_needs_the_reference():
    """At the default target (relMSE 0.01) no approximation's measured floor qualifies."""
    assert min(BIAS_FLOOR.values()) > DEFAULT_TARGET
    c = choose_method((0.97, 0.88, 0.7), 8.0, 0.5, None)
    assert c.method == "volumetric" and "optical radius 4" in c.reason


def test_a_loose_target_takes_the_cheapest_method_that_meets_it():
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.5).method == "backlight"
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.45).method == "diffusion"
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.35).method == "volumetric"


def test_the_regime_picks_the_floors():
    """A solid sphere lit from the camera's side pays only the solid scenes' floors: at target 0.35
    backlight (solid floor 0.314) instead of volumetric; lit from behind it pays the backlit
    slab's too (diffusion 0.41, backlight still 0.314), as a mesh the torus's (backlight 0.474)."""
    solid = frozenset()
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.35, regimes=solid).method == "backlight"
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.3, regimes=solid).method == "single_scatter"
    backlit = frozenset({"backlit"})
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.35, regimes=backlit).method == "backlight"
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.3, regimes=backlit).method == "volumetric"
    mesh = frozenset({"mesh"})
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.35, regimes=mesh).method == "diffusion"
    assert "(mesh, solid)" in choose_method((0.9,) * 3, 8.0, 0.5, 0.35, regimes=mesh).reason


@pytest.mark.parametrize(("lights", "backlit"), [
    ([{"type": "point", "position": [0, 0.5, 3], "intensity": [5, 5, 5]}], False),
    ([{"type": "point", "position": [0, 0.2, -3], "intensity": [5, 5, 5]}], True),
    ([{"type": "directional", "direction": [0, 0, 1], "irradiance": [2, 2, 2]}], True),
    ([{"type": "directional", "direction": [0, -1, -1], "irradiance": [2, 2, 2]}], False),
])
def test_light_placement_is_read_from_the_scene(lights, backlit):
    data = wax_scene("auto", target=0.3)
    data["lights"] = lights
    scene = load_scene(data)
    objects = [o for o in scene.objects if o.material == "wax"]
    assert ("backlit" in scene_regimes(scene, objects)) == backlit
    expected = "volumetric" if backlit else "single_scatter"
    assert auto_choice(scene, "wax").method == expected


@pytest.mark.parametrize(("albedo", "density", "expected"), [
    ((0.0, 0.0, 0.0), 50.0, "dielectric"),  # only absorbs: an absorbing glass is exact
    ((0.9, 0.9, 0.9), 0.005, "dielectric"),  # τ·a = 0.0023 < 0.01: effectively clear
    ((0.9, 0.9, 0.9), 0.05, "volumetric"),
])
def test_regimes_that_need_no_subsurface_model(albedo, density, expected):
    assert choose_method(albedo, density, 0.5, None).method == expected


def test_compile_renders_what_auto_chose_and_reports_why():
    """auto's image is the chosen method's image, sample for sample, and the choice is reported."""
    cs = compile_scene(load_scene(wax_scene("auto")))
    assert cs.info["auto"]["wax"]["method"] == "volumetric"
    np.testing.assert_array_equal(render(cs), render(wax_scene("volumetric")))
    loose = compile_scene(load_scene(wax_scene("auto", target=0.5)))
    assert loose.info["auto"]["wax"]["method"] == "backlight"
    np.testing.assert_array_equal(render(loose), render(wax_scene("backlight", target=0.5)))


def test_an_absorbing_only_material_is_rendered_as_absorbing_glass():
    """Albedo 0: the random walk never scatters, so it is Beer–Lambert glass: the same image as
    the dielectric auto substitutes, up to the noise of the walk's grey free-flight sampling
    (which the dielectric replaces by exact attenuation): frame means within 2 %."""
    data = wax_scene("auto", albedo=[0.0, 0.0, 0.0])
    data["render"]["spp"] = 64
    cs = compile_scene(load_scene(data))
    assert cs.info["auto"]["wax"]["method"] == "dielectric"
    ref = wax_scene("volumetric", albedo=[0.0, 0.0, 0.0])
    ref["render"]["spp"] = 64
    a, b = render(cs), render(ref)
    np.testing.assert_allclose(a.mean(axis=(0, 1)), b.mean(axis=(0, 1)), rtol=0.02)


def test_chromatic_media_are_judged_by_their_worst_channel():
    """Clear only if the densest channel is; opaque only if the farthest-reaching channel is;
    in between volumetric, whatever the target: the approximations' floors are grey-measured."""
    # Clear in red and green, not in blue: not clear
    assert choose_method((0.9,) * 3, (0.001, 0.001, 8.0), 0.5, 0.5).method == "volumetric"
    assert choose_method((0.9,) * 3, (0.001, 0.001, 0.002), 0.5, 0.5).method == "dielectric"
    # At a target the grey wax meets with backlight, the chromatic one still gets the reference
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.5).method == "backlight"
    c = choose_method((0.9,) * 3, (4.0, 8.0, 16.0), 0.5, 0.5)
    assert c.method == "volumetric" and "chromatic" in c.reason
    # Nearly opaque in blue, deep in red: the red channel's reach decides, not opaque
    footprint = 0.05
    assert choose_method((0.95,) * 3, (3000.0,) * 3, 0.5, None, footprint=footprint,
                         ior=1.4).method == "opaque"
    assert choose_method((0.95,) * 3, (3.0, 300.0, 3000.0), 0.5, None, footprint=footprint,
                         ior=1.4).method == "volumetric"
    assert choose_method((0.95,) * 3, (2000.0, 3000.0, 4000.0), 0.5, None, footprint=footprint,
                         ior=1.4).method == "opaque"


def test_auto_on_a_chromatic_scene_renders_what_it_chose():
    scene = load_scene(wax_scene("auto", target=0.5, density=[4.0, 8.0, 16.0]))
    choice = auto_choice(scene, "wax")
    assert choice.method == "volumetric"
    assert compile_scene(scene).info["auto"]["wax"]["method"] == "volumetric"
