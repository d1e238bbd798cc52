"""``method: "auto"`` with a textured ``translucent.albedo``: the choice rests on the texture's
mean, and lands on a method a texture can colour (``renderer.materials.auto.for_a_texture``), or
the scene is refused where auto would render a glass."""

import numpy as np
import pytest

from renderer.materials.auto import REGIME_FLOOR
from renderer.materials.bsdf import DIFFUSION, ROUGH_DIFFUSION, SINGLE_SCATTER
from renderer.materials.diffusion import OPAQUE
from renderer.render import render_buffer
from renderer.scene import SceneError, load_scene
from renderer.scene.compile import compile_scene

CHECKER = {"type": "checkerboard", "color0": [0.2, 0.3, 0.4], "color1": [0.8, 0.7, 0.6],
           "scale": [4, 4]}


def scene_with(wax: dict, width=16, spp=8) -> dict:
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": width, "height": width},
        "render": {"spp": spp, "max_depth": -1, "seed": 3},
        "background": [1.0, 1.0, 1.0],
        "materials": {"wax": {"type": "translucent", "method": "auto", "ior": 1.4,
                              "albedo": CHECKER} | wax},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "wax"}],
    }


def compiled(wax: dict, **kw):
    return compile_scene(load_scene(scene_with(wax, **kw)))


def test_a_textured_albedo_takes_the_approximation_with_the_lowest_floor():
    """At the default target (0.01) no approximation's floor is low enough, so a grey albedo gets
    volumetric; a texture cannot colour a medium, so auto takes the approximation with the
    lowest floor of the scene's regimes (a solid sphere lit from the camera's side: single_scatter,
    0.236), the texture bound to its albedo slots. The choice rests on the texture's mean: the
    checkerboard's (0.2..0.8 per channel) is 0.5 in every channel."""
    c = compiled({"density": 5.0})
    assert int(c.arrays.mat_kind[0]) == SINGLE_SCATTER
    choice = c.info["auto"]["wax"]
    lowest = min(REGIME_FLOOR, key=lambda m: REGIME_FLOOR[m]["solid"])
    assert lowest == "single_scatter" and choice["expected_error"] == REGIME_FLOOR[lowest]["solid"]
    assert "albedo 0.5:" in choice["reason"]
    assert "textured albedo colours a surface" in choice["reason"]
    assert (c.arrays.mat_tex[0] >= 0).any()  # the texture is bound, not dropped
    # the same material with an RGB albedo: volumetric
    plain = compile_scene(load_scene(scene_with({"density": 5.0, "albedo": [0.5, 0.5, 0.5]})))
    assert plain.info["auto"]["wax"]["method"] == "volumetric"


def test_the_texture_colours_the_render():
    """The chosen method renders the checkerboard: the image has its two colours' contrast (a
    uniform albedo of its mean would not), and is finite."""
    buf = render_buffer(load_scene(scene_with({"density": 5.0}, width=32, spp=16)))
    img = buf.sum / buf.count[..., None]
    assert np.isfinite(img).all()
    body = img[10:22, 10:22]
    assert (body[..., 0] - body[..., 2]).std() > 0.05  # red-blue differs across the squares


def test_a_rough_textured_albedo_takes_diffusion_behind_its_rough_coat():
    """Rough: of the approximations with a measured floor only diffusion has a rough coat."""
    c = compiled({"density": 5.0, "roughness": 0.3})
    assert int(c.arrays.mat_kind[0]) == ROUGH_DIFFUSION
    assert "with a rough coat" in c.info["auto"]["wax"]["reason"]


def test_an_effectively_opaque_textured_albedo_takes_diffusion_not_the_opaque_limit():
    """The opaque limit's albedo is one colour (from walks); diffusion's profile follows the
    texture at each hit."""
    grey = compile_scene(load_scene(scene_with({"density": 1e5, "albedo": [0.5, 0.5, 0.5]})))
    assert grey.info["auto"]["wax"]["method"] == "opaque"
    c = compiled({"density": 1e5})
    assert int(c.arrays.mat_kind[0]) == DIFFUSION and c.arrays.mat_param[0, OPAQUE] == 0.0
    assert "opaque limit takes one colour" in c.info["auto"]["wax"]["reason"]


def test_a_textured_albedo_auto_would_render_as_glass_is_refused():
    """Effectively clear: auto renders an absorbing glass, which a texture cannot colour; the
    error names the albedo and says why."""
    with pytest.raises(SceneError) as info:
        load_scene(scene_with({"density": 1e-5}))
    (field, message), = info.value.errors
    assert field == "materials.wax.albedo"
    assert message.startswith("a texture cannot colour this material: method auto renders it "
                              "as a glass (optical radius")


def test_volumetric_still_refuses_a_textured_albedo():
    with pytest.raises(SceneError) as info:
        load_scene(scene_with({"method": "volumetric", "density": 5.0}))
    (field, message), = info.value.errors
    assert field == "materials.wax" and "takes an RGB albedo (the albedo belongs to the medium)" \
        in message
