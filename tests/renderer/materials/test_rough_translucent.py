"""A rough boundary on a translucent medium (``translucent.roughness``, method volumetric): the
kind ROUGH_TRANSLUCENT. Mitsuba 3 agreement (roughdielectric over a homogeneous medium) is in
tests/reference/test_mitsuba_bridge.py; here the scene rules, auto's choice, the furnace and the
failure regime."""

import numpy as np
import pytest

from renderer.materials.bsdf import ROUGH_DIELECTRIC, ROUGH_TRANSLUCENT, TRANSLUCENT
from renderer.render import render_buffer
from renderer.scene import SceneError, load_scene
from renderer.scene.compile import compile_scene


def scene_with(wax: dict, background=(1.0, 1.0, 1.0), spp=64) -> dict:
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": 16, "height": 16},
        "render": {"spp": spp, "max_depth": -1, "seed": 3},
        "background": list(background),
        "materials": {"wax": {"type": "translucent", "ior": 1.4} | wax},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "wax"}],
    }


@pytest.mark.parametrize("method", ["single_scatter", "backlight"])
def test_the_approximations_without_a_boundary_refuse_a_rough_one(method):
    """(diffuse_entry and diffusion render a rough coat: tests/renderer/integrators/
    test_rough_coats.py)"""
    with pytest.raises(SceneError) as info:
        load_scene(scene_with({"method": method, "roughness": 0.3}))
    (field, message), = info.value.errors
    assert field == "materials.wax" and "has no dielectric boundary to roughen" in message


def test_kinds_compiled_for_a_rough_boundary():
    def kind(wax):
        return int(compile_scene(load_scene(scene_with(wax))).arrays.mat_kind[0])

    assert kind({"roughness": 0.3}) == ROUGH_TRANSLUCENT
    assert kind({"roughness": 0.0}) == TRANSLUCENT
    assert kind({"roughness": 0.3, "ior": 1.0}) == TRANSLUCENT  # index-matched: null, rough or not
    # auto: a scattering medium behind a rough boundary is rendered by volumetric, whatever its
    # density (the opaque limit and the approximations have a smooth coat) ...
    for density in (3.0, 300.0):
        compiled = compile_scene(load_scene(scene_with(
            {"method": "auto", "roughness": 0.3, "albedo": [0.9, 0.9, 0.9], "density": density})))
        assert int(compiled.arrays.mat_kind[0]) == ROUGH_TRANSLUCENT
        assert "rough boundary" in compiled.info["auto"]["wax"]["reason"]
    # ... and a clear one by rough glass
    clear = compile_scene(load_scene(scene_with(
        {"method": "auto", "roughness": 0.3, "albedo": [0.9, 0.9, 0.9], "density": 1e-5})))
    assert int(clear.arrays.mat_kind[0]) == ROUGH_DIELECTRIC


def mean_and_se(buf):
    var = buf.variance_of_mean()[4:12, 4:12]
    mean = (buf.sum[4:12, 4:12] / buf.count[4:12, 4:12, None]).mean(axis=(0, 1))
    return mean, np.sqrt(var.sum(axis=(0, 1))) / var[..., 0].size


def test_a_white_furnace_through_a_rough_boundary_loses_only_what_the_microfacets_drop():
    """A non-absorbing medium (albedo 1) behind a rough boundary in a white furnace: no energy
    from nowhere (below 1), and only what the single-scattering microfacet model drops at each
    crossing is lost, as rough glass loses it (the sphere of rough glass of the same α, within
    noise; at α 0.05 nearly nothing is lost)."""
    wax = {"albedo": [1.0, 1.0, 1.0], "density": 2.0}
    rough, se = mean_and_se(render_buffer(load_scene(scene_with(wax | {"roughness": 0.5}))))
    assert (rough < 1.0 - 4 * se).all() and (rough > 0.55).all(), (rough, se)
    glossy, se2 = mean_and_se(render_buffer(load_scene(scene_with(wax | {"roughness": 0.05}))))
    assert (np.abs(glossy - 1.0) < 4 * se2 + 0.01).all(), (glossy, se2)


def test_dense_media_and_extreme_alpha_stay_finite():
    """The failure regime: a nearly opaque medium (σt 10⁴) behind boundaries from nearly smooth
    to α 1, with albedo 0.999 — no NaN, no dropped sample, no energy from nowhere."""
    for alpha in (1e-4, 1.0):
        for density in (1e-3, 1e4):
            buf = render_buffer(load_scene(scene_with(
                {"roughness": alpha, "albedo": [0.999, 0.5, 0.0], "density": density}, spp=32)))
            assert np.isfinite(buf.sum).all() and buf.dropped.sum() == 0
            mean, se = mean_and_se(buf)
            assert (mean < 1.0 + 4 * se).all(), (alpha, density, mean, se)
