"""``method: "auto"``: the choice, its reason, and that the chosen model is what gets rendered."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from renderer.materials.auto import (
    BIAS_FLOOR,
    CHROMATIC_FLOOR,
    DEFAULT_TARGET,
    MIXED_FLOOR,
    REGIME_FLOOR,
    auto_choice,
    channel_regimes,
    choose_method,
    describe_choice,
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


def test_the_choice_is_described_with_its_bias():
    """What the CLI and the job API say: an exact method has no bias, its error is the samples'
    noise; an approximation its measured floor over the object's pixels, the noise on top (it
    said "expected relMSE 0" for the reference, as if its image had no error)."""
    exact = choose_method((0.97, 0.88, 0.7), 8.0, 0.5, None)
    said = describe_choice(exact.reason, exact.expected_error)
    assert said.startswith(exact.reason)
    assert said.endswith("; expected bias none (unbiased: the error is the samples' noise alone)")
    rough = choose_method((0.9,) * 3, 8.0, 0.5, 0.35, regimes=frozenset())
    assert rough.method == "backlight"
    assert rough.expected_error == REGIME_FLOOR["backlight"]["solid"]
    assert describe_choice(rough.reason, rough.expected_error).endswith(
        "; expected bias relMSE 0.314 over the object's pixels (the samples' noise comes on top)")


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


@pytest.mark.parametrize(("albedo", "density", "footprint", "expected"), [
    # the chromatic wax of the examples: deep in red, translucent in every channel
    ((0.97, 0.88, 0.7), (3.0, 8.0, 16.0), 0.05, ("translucent",) * 3),
    # blue made nearly opaque (reach 0.0032 under the pixel 0.05): deep in red, opaque in blue
    ((0.97, 0.88, 0.5), (3.0, 8.0, 1000.0), 0.05, ("translucent", "translucent", "opaque")),
    # the same with the pixel unknown: nothing is opaque
    ((0.97, 0.88, 0.5), (3.0, 8.0, 1000.0), 0.0, ("translucent",) * 3),
    # thin in red (scattered fraction 0.9·0.01·0.5 = 0.0045 <= 0.01), absorbing in green
    ((0.9, 0.0, 0.9), (0.01, 8.0, 8.0), 0.05, ("clear", "absorbing", "translucent")),
    # every channel dense: opaque in each
    ((0.95, 0.95, 0.95), (2000.0, 3000.0, 4000.0), 0.05, ("opaque",) * 3),
])
def test_each_channel_is_classified_by_its_own_albedo_and_density(albedo, density, footprint,
                                                                  expected):
    assert channel_regimes(albedo, density, 0.5, 0.01, ior=1.4, footprint=footprint) == expected


def test_a_channel_is_in_the_regime_a_grey_medium_at_its_values_would_be():
    """Channel k's regime is the grey medium's at (albedo_k, σt_k): what choose_method picks for
    that grey medium (dielectric for clear/absorbing, opaque, else a subsurface method)."""
    albedo, density = (0.97, 0.0, 0.5), (0.004, 8.0, 1000.0)
    kinds = channel_regimes(albedo, density, 0.5, 0.01, ior=1.4, footprint=0.05)
    grey = {"clear": "dielectric", "absorbing": "dielectric", "opaque": "opaque",
            "translucent": "volumetric"}
    for k in range(3):
        c = choose_method((albedo[k],) * 3, density[k], 0.5, None, ior=1.4, footprint=0.05)
        assert c.method == grey[kinds[k]], (k, kinds[k], c.reason)


def test_chromatic_media_take_the_method_whose_floor_holds_in_every_channel():
    solid, backlit, mesh = frozenset(), frozenset({"backlit"}), frozenset({"mesh"})
    wax = ((0.97, 0.88, 0.7), (3.0, 8.0, 16.0))
    # Every channel translucent: the chromatic floors (the grey suite's and the chromatic's)
    c = choose_method(*wax, 0.5, 0.35, regimes=solid, footprint=0.05)
    assert (c.method, c.expected_error) == ("backlight", CHROMATIC_FLOOR["backlight"]["solid"])
    assert "R translucent, G translucent, B translucent" in c.reason
    assert "chromatic floor" in c.reason
    # backlit: the chromatic slab's floors (single_scatter 0.436 > grey 0.377)
    assert choose_method(*wax, 0.5, 0.4, regimes=backlit).method == "backlight"
    assert CHROMATIC_FLOOR["single_scatter"]["backlit"] > REGIME_FLOOR["single_scatter"][
        "backlit"]
    # no chromatic mesh measured, unknown regimes: the reference
    for regimes in (mesh, None):
        c = choose_method(*wax, 0.5, 1.0, regimes=regimes)
        assert c.method == "volumetric" and "was measured" in c.reason
    # the default target: no approximation is close enough
    assert choose_method(*wax, 0.5, None, regimes=solid).method == "volumetric"
    # rough: volumetric
    assert choose_method(*wax, 0.5, 1.0, regimes=solid, rough=True).method == "volumetric"


def test_mixed_regimes_take_the_floors_measured_on_mixed_scenes():
    """Nearly opaque in blue, deep in red: an approximation only where its floor over the
    mixed-regime scenes meets the target; a clear or absorbing channel beside a scattering one,
    volumetric; every channel clear or absorbing, a dielectric; every channel opaque, opaque."""
    solid = frozenset()
    mixed = ((0.97, 0.88, 0.5), (3.0, 8.0, 1000.0))
    for target in (0.01, 0.2, 0.3, 0.5, 1.0):
        c = choose_method(*mixed, 0.5, target, regimes=solid, footprint=0.05)
        assert "R translucent, G translucent, B opaque" in c.reason
        ok = [m for m in BIAS_FLOOR if MIXED_FLOOR[m]["solid"] <= target]
        assert c.method == (ok[0] if ok else "volumetric"), (target, c.reason)
        if ok:
            assert "mixed floor" in c.reason
    for m in BIAS_FLOOR:
        for regime in ("solid", "backlit"):
            assert MIXED_FLOOR[m][regime] >= CHROMATIC_FLOOR[m][regime]
    # clear in red beside scattering green and blue: volumetric, at any target
    c = choose_method((0.9, 0.9, 0.9), (0.001, 8.0, 16.0), 0.5, 1.0, regimes=solid)
    assert c.method == "volumetric" and "clear or absorbing" in c.reason
    # absorbing in blue beside scattering red: volumetric
    assert choose_method((0.9, 0.9, 0.0), (3.0, 8.0, 16.0), 0.5, 1.0,
                         regimes=solid).method == "volumetric"
    # clear in red and green, absorbing in blue: an absorbing glass
    c = choose_method((0.9, 0.9, 0.0), (0.001, 0.002, 8.0), 0.5, None)
    assert c.method == "dielectric" and c.expected_error == pytest.approx(0.9 * 0.002 * 0.5)
    assert choose_method((0.9,) * 3, (0.001, 0.001, 0.002), 0.5, 0.5).method == "dielectric"
    # opaque in every channel, each judged by its own reach
    footprint = 0.05
    assert choose_method((0.95,) * 3, (2000.0, 3000.0, 4000.0), 0.5, None, footprint=footprint,
                         ior=1.4).method == "opaque"
    assert choose_method((0.95,) * 3, (3.0, 300.0, 3000.0), 0.5, None, footprint=footprint,
                         ior=1.4).method == "volumetric"


def test_grey_media_keep_the_grey_rule():
    """One σt: the rule of the grey suite, whatever the channels' albedos."""
    assert choose_method((0.9,) * 3, 8.0, 0.5, 0.5).method == "backlight"
    assert choose_method((0.97, 0.88, 0.7), 8.0, 0.5, 0.3,
                         regimes=frozenset()).method == "single_scatter"
    assert "translucent" not in choose_method((0.9,) * 3, 8.0, 0.5, 0.5).reason


def test_auto_on_a_chromatic_scene_renders_what_it_chose():
    scene = load_scene(wax_scene("auto", target=0.5, density=[4.0, 8.0, 16.0]))
    choice = auto_choice(scene, "wax")
    assert choice.method == "backlight" and "chromatic floor (solid)" in choice.reason
    cs = compile_scene(scene)
    assert cs.info["auto"]["wax"]["method"] == "backlight"
    np.testing.assert_array_equal(
        render(cs), render(wax_scene("backlight", target=0.5, density=[4.0, 8.0, 16.0])))
    tight = load_scene(wax_scene("auto", density=[4.0, 8.0, 16.0]))
    assert compile_scene(tight).info["auto"]["wax"]["method"] == "volumetric"
