"""AOVs (renderer.film.aov) and the multi-layer EXR they are written to.

The traced layers are checked against closed forms: a diffuse plane filling the view has its
albedo everywhere, its normal, and the depth it was placed at (the depth is measured along the
viewing axis, so it is the same at every pixel of a plane square to it); a glass sphere's albedo
shows the plane behind it.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from renderer.film.aov import buffer_aovs, render_aovs
from renderer.film.buffer import SampleBuffer
from renderer.scene import SceneError, load_scene
from renderer.scene.compile import compile_scene

ALBEDO = (0.2, 0.5, 0.8)


def plane_scene(distance: float, extra=(), materials=None, aovs=("albedo", "normal", "depth")):
    """A camera at the origin looking down −z at a diffuse plane z = −distance that fills the
    view (its normal +z faces the camera)."""
    big = 50.0 * distance
    return {
        "camera": {"position": [0, 0, 0], "look_at": [0, 0, -1], "fov": 40.0},
        "film": {"width": 16, "height": 12, "aovs": list(aovs)},
        "render": {"spp": 4, "seed": 3},
        "materials": {"wall": {"type": "diffuse", "albedo": list(ALBEDO)}, **(materials or {})},
        "objects": [{"type": "quad", "origin": [-big, -big, -distance], "edge1": [2 * big, 0, 0],
                     "edge2": [0, 2 * big, 0], "material": "wall"}, *extra],
        "lights": [{"type": "point", "position": [0, 0, 0], "intensity": [1, 1, 1]}],
    }


def test_diffuse_plane_albedo_normal_depth():
    compiled = compile_scene(load_scene(plane_scene(2.5)))
    aov = render_aovs(compiled, ["albedo", "normal", "depth"], spp=3)
    assert aov["albedo"].shape == (12, 16, 3) and aov["albedo"].dtype == np.float32
    np.testing.assert_allclose(aov["albedo"], np.broadcast_to(ALBEDO, (12, 16, 3)), atol=1e-6)
    np.testing.assert_allclose(aov["normal"], np.broadcast_to((0, 0, 1), (12, 16, 3)),
                               atol=1e-6)
    assert aov["depth"].shape == (12, 16, 1)
    np.testing.assert_allclose(aov["depth"], 2.5, rtol=1e-6)


def test_the_rows_threads_do_not_change_the_layers():
    """The AOV pass deals rows out to threads (renderer.jit.run_chunks): any number of them,
    more than the rows included, gives the layers bit for bit."""
    glass = {"glass": {"type": "dielectric", "ior": 1.5}}
    sphere = {"type": "sphere", "center": [0, 0, -2], "radius": 0.6, "material": "glass"}
    compiled = compile_scene(load_scene(plane_scene(3.0, [sphere], glass)))
    one = render_aovs(compiled, ["albedo", "normal", "depth"], spp=2, threads=1)
    for threads in (2, 5, 40):
        many = render_aovs(compiled, ["albedo", "normal", "depth"], spp=2, threads=threads)
        for name in one:
            np.testing.assert_array_equal(many[name], one[name])


def test_normal_faces_the_viewer_from_behind():
    # the same plane with its edges swapped: outward normal −z, away from the camera
    scene = plane_scene(1.0)
    q = scene["objects"][0]
    q["edge1"], q["edge2"] = q["edge2"], q["edge1"]
    aov = render_aovs(compile_scene(load_scene(scene)), ["normal"])
    np.testing.assert_allclose(aov["normal"], np.broadcast_to((0, 0, 1), (12, 16, 3)), atol=1e-6)


def test_glass_sphere_albedo_shows_what_is_behind():
    glass = {"glass": {"type": "dielectric", "ior": 1.5}}
    sphere = {"type": "sphere", "center": [0, 0, -3], "radius": 0.8, "material": "glass"}
    compiled = compile_scene(load_scene(plane_scene(6.0, [sphere], glass)))
    aov = render_aovs(compiled, ["albedo", "depth"], spp=2)
    # through clear glass the plane's albedo is seen everywhere, the sphere included
    np.testing.assert_allclose(aov["albedo"], np.broadcast_to(ALBEDO, (12, 16, 3)), atol=1e-5)
    # while the depth is the first surface's: the sphere's front (3 − 0.8 at the centre)
    centre = aov["depth"][5:7, 7:9, 0]
    assert np.all(centre < 2.3) and np.all(centre > 2.15)
    assert aov["depth"][0, 0, 0] == pytest.approx(6.0, rel=1e-6)


def test_mirror_tints_albedo_and_translucent_stops_at_its_surface():
    mats = {"gold": {"type": "mirror", "reflectance": [0.9, 0.6, 0.3]},
            "wax": {"type": "translucent", "method": "volumetric", "ior": 1.3,
                    "albedo": [0.9, 0.8, 0.7], "density": 5.0}}
    # a mirror quad square to the view, 1 in front: the camera sees the mirror, then the plane
    # behind the camera (the mirror of plane_scene's plane, at z = +4)
    big = 100.0
    objects = [{"type": "quad", "origin": [-big, -big, -1], "edge1": [2 * big, 0, 0],
                "edge2": [0, 2 * big, 0], "material": "gold"},
               {"type": "quad", "origin": [-big, -big, 4], "edge1": [0, 2 * big, 0],
                "edge2": [2 * big, 0, 0], "material": "wall"}]
    scene = plane_scene(2.0, materials=mats)
    scene["objects"] = objects
    aov = render_aovs(compile_scene(load_scene(scene)), ["albedo", "normal", "depth"])
    np.testing.assert_allclose(aov["albedo"], np.broadcast_to(
        np.multiply(ALBEDO, (0.9, 0.6, 0.3)), (12, 16, 3)), atol=1e-6)
    np.testing.assert_allclose(aov["normal"], np.broadcast_to((0, 0, -1), (12, 16, 3)),
                               atol=1e-6)
    np.testing.assert_allclose(aov["depth"], 1.0, rtol=1e-6)

    # a translucent sphere, smooth or under a rough coat, any method: its medium's albedo
    sphere = {"type": "sphere", "center": [0, 0, -3], "radius": 2.0, "material": "wax"}
    for method, roughness in (("volumetric", 0.0), ("diffusion", 0.3), ("diffuse_entry", 0.3),
                              ("single_scatter", 0.0)):
        mats["wax"].update(method=method, roughness=roughness)
        aov = render_aovs(compile_scene(load_scene(plane_scene(6.0, [sphere], mats))),
                          ["albedo"])
        np.testing.assert_allclose(aov["albedo"][6, 8], (0.9, 0.8, 0.7), atol=1e-6)


def test_buffer_aovs_are_the_buffers_variance_and_count():
    buf = SampleBuffer.empty(0, 0, 3, 2)
    rng = np.random.default_rng(1)
    for _ in range(5):
        sample = rng.random((2, 3, 3))
        buf.sum += sample
        buf.sum_sq += sample * sample
        buf.count += 1
    buf.count[0, 0] += 0  # every pixel 5 samples
    out = buffer_aovs(buf, ["spp", "variance"])
    np.testing.assert_array_equal(out["spp"][..., 0], 5.0)
    np.testing.assert_allclose(out["variance"], buf.variance_of_mean(), rtol=1e-6)


def test_unknown_aov_is_refused_naming_the_field():
    scene = plane_scene(1.0, aovs=("albedo", "alpha"))
    with pytest.raises(SceneError) as err:
        load_scene(scene)
    assert any(where == "film.aovs[1]" and "alpha" in message
               for where, message in err.value.errors)


def test_multilayer_exr_reads_back_with_its_layers():
    import OpenEXR

    from renderer.film.image_io import decode_exr, encode_exr_layers

    rng = np.random.default_rng(2)
    beauty = rng.random((4, 5, 3)).astype(np.float32)
    layers = {"albedo": rng.random((4, 5, 3)).astype(np.float32),
              "normal": rng.random((4, 5, 3)).astype(np.float32) * 2 - 1,
              "depth": rng.random((4, 5, 1)).astype(np.float32) * 10,
              "variance": rng.random((4, 5, 3)).astype(np.float32),
              "spp": np.full((4, 5, 1), 64, np.float32)}
    data = encode_exr_layers(beauty, layers)
    exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
    channels = {k: c.pixels for k, c in exr.channels().items()}
    assert set(channels) == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "normal.X",
                             "normal.Y", "normal.Z", "depth.Z", "variance.R", "variance.G",
                             "variance.B", "spp.Y"}
    assert channels["albedo.R"].dtype == np.float16 and channels["normal.X"].dtype == np.float16
    assert channels["R"].dtype == np.float32 and channels["depth.Z"].dtype == np.float32
    np.testing.assert_array_equal(np.stack([channels[c] for c in "RGB"], -1), beauty)
    np.testing.assert_allclose(channels["albedo.G"], layers["albedo"][..., 1], atol=1e-3)
    np.testing.assert_allclose(channels["normal.Z"], layers["normal"][..., 2], atol=1e-3)
    np.testing.assert_array_equal(channels["depth.Z"], layers["depth"][..., 0])
    np.testing.assert_array_equal(channels["spp.Y"], 64.0)
    # the beauty is what an RGB reader sees
    np.testing.assert_array_equal(decode_exr(data), beauty)
