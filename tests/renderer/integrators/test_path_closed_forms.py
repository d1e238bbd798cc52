"""The path tracer against closed-form radiance: furnaces, point and directional lights, a slab.

Each test renders a scene whose exact pixel values are known and compares with a tolerance derived
from the sample count. The scenes are small (a few thousand pixels) so the whole module runs in a
few seconds once the kernels are compiled.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.render import render_buffer
from renderer.scene import load_scene


def scene(objects, materials, *, lights=(), background=(0, 0, 0), camera=None, film=(32, 24),
          spp=16, max_depth=-1, seed=3):
    return load_scene({
        "camera": camera or {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 40},
        "film": {"width": film[0], "height": film[1]},
        "render": {"spp": spp, "max_depth": max_depth, "seed": seed},
        "background": list(background),
        "materials": materials,
        "objects": objects,
        "lights": list(lights),
    })


def inward_box(size: float, material: str, emission) -> list[dict]:
    """A closed cube of six quads whose normals face inwards (so they emit into the box)."""
    s = size
    faces = [
        ([-s, -s, -s], [0, 2 * s, 0], [0, 0, 2 * s]),  # x = −s, normal +x
        ([s, -s, -s], [0, 0, 2 * s], [0, 2 * s, 0]),  # x = +s, normal −x
        ([-s, -s, -s], [0, 0, 2 * s], [2 * s, 0, 0]),  # y = −s, normal +y
        ([-s, s, -s], [2 * s, 0, 0], [0, 0, 2 * s]),  # y = +s, normal −y
        ([-s, -s, -s], [2 * s, 0, 0], [0, 2 * s, 0]),  # z = −s, normal +z
        ([-s, -s, s], [0, 2 * s, 0], [2 * s, 0, 0]),  # z = +s, normal −z
    ]
    return [{"type": "quad", "origin": o, "edge1": e1, "edge2": e2, "material": material,
             "emission": list(emission)} for o, e1, e2 in faces]


def test_inward_box_faces_face_inwards():
    for quad in inward_box(1.0, "m", (1, 1, 1)):
        normal = np.cross(quad["edge1"], quad["edge2"])
        centre = np.asarray(quad["origin"]) + 0.5 * np.add(quad["edge1"], quad["edge2"])
        assert np.dot(normal, centre) < 0


def test_outside_furnace_convex_sphere():
    """A convex diffuse sphere of albedo ρ under a uniform background L = 1 has radiance ρ.

    Every direction above a point of a convex object sees the background, so Lo = ρ·L exactly.
    The background pixels must be exactly 1. Tolerance: 6 standard errors of the mean over the
    sphere's pixels, estimated from the sample buffer itself.
    """
    for rho in (1.0, 0.6):
        sc = scene([{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "d"}],
                   {"d": {"type": "diffuse", "albedo": [rho, rho, rho]}}, background=(1, 1, 1),
                   spp=32)
        buf = render_buffer(sc)
        img = buf.mean()
        # The sphere covers the centre of the frame, the background the corners
        assert np.all(img[0, 0] == 1.0) and np.all(img[-1, -1] == 1.0)
        centre = img[8:16, 12:20]
        var = buf.variance_of_mean()[8:16, 12:20]
        se = math.sqrt(var.sum()) / var.size
        assert abs(centre.mean() - rho) < 6 * se + 1e-12, (rho, centre.mean(), se)
        if rho == 1.0:
            # White furnace: every single pixel is 1 within its own noise
            assert np.all(np.abs(centre - 1.0) < 6 * np.sqrt(var) + 1e-9)


@pytest.mark.parametrize("kernel", ["scalar", "packet"])
@pytest.mark.parametrize("max_depth", [0, 1, 2, 5, -1])
def test_inside_furnace_geometric_series(max_depth, kernel):
    """Inside a closed box whose walls have albedo ρ and emit Le, every point sees
    L = Le·(1 + ρ + … + ρ^k) = Le·(1 − ρ^(k+1))/(1 − ρ) with k = max_depth scattering events,
    and Le/(1 − ρ) for an unlimited depth. This pins down the meaning of max_depth (scene format
    v1: it counts scattering events) and that Russian roulette at unlimited depth is unbiased.
    Tolerance: 6 standard errors of the frame mean (plus 1e-12 where the estimator is exact).
    """
    rho, le = 0.7, 0.5
    sc = scene(inward_box(1.0, "wall", (le, le, le)),
               {"wall": {"type": "diffuse", "albedo": [rho, rho, rho]}},
               camera={"position": [0.1, 0.2, 0.3], "look_at": [0, 0, -1], "fov": 90},
               spp=64, max_depth=max_depth)
    buf = render_buffer(sc, kernel=kernel)  # the box is a scene the packet kernel covers
    expected = le / (1 - rho) if max_depth < 0 else le * (1 - rho ** (max_depth + 1)) / (1 - rho)
    var = buf.variance_of_mean()
    se = math.sqrt(var[..., 0].sum()) / var[..., 0].size
    got = buf.mean()[..., 0].mean()
    assert abs(got - expected) < 6 * se + 1e-12, (got, expected, se)


def _plane_scene(lights, rho=0.5, film=(24, 24)):
    # A large diffuse plane z = 0 seen from above at an angle
    return scene([{"type": "quad", "origin": [-50, -50, 0], "edge1": [100, 0, 0],
                   "edge2": [0, 100, 0], "material": "d"}],
                 {"d": {"type": "diffuse", "albedo": [rho, rho, rho]}}, lights=lights,
                 camera={"position": [0.3, -2.0, 3.0], "look_at": [0, 0, 0], "up": [0, 0, 1],
                         "fov": 30}, film=film, spp=16, max_depth=-1)


def _pixel_points(sc, film, sub=8):
    """Where each sub-pixel ray of the camera meets the plane z = 0 (sub × sub per pixel)."""
    cam = sc.camera
    pos = np.asarray(cam.position, float)
    fwd = np.asarray(cam.look_at, float) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan_half = math.tan(math.radians(cam.fov) / 2)
    w, h = film
    offs = (np.arange(sub) + 0.5) / sub
    xs = (np.arange(w)[:, None] + offs[None, :]).ravel()
    ys = (np.arange(h)[:, None] + offs[None, :]).ravel()
    sx = (2 * xs / w - 1) * tan_half * w / h
    sy = (1 - 2 * ys / h) * tan_half
    d = fwd[None, None] + sy[:, None, None] * up + sx[None, :, None] * right
    t = -pos[2] / d[..., 2]
    return pos + t[..., None] * d  # (h·sub, w·sub, 3)


def _box_filter(values, sub):
    h, w = values.shape[0] // sub, values.shape[1] // sub
    return values.reshape(h, sub, w, sub).mean(axis=(1, 3))


def test_point_light_on_diffuse_plane():
    """L = I·ρ·cosθ/(π r²) at every point of a plane lit by a point light.

    The only randomness left is the pixel jitter (the light is a delta light and the plane cannot
    see itself), so the pixel mean matches the box-filtered closed form to ~1/√spp of the
    radiance variation inside a pixel; 1 % relative is far outside that and far inside any error
    of a factor (π, cosθ, r²).
    """
    intensity, rho = 7.0, 0.5
    light = np.array([0.4, 0.2, 1.5])
    sc = _plane_scene([{"type": "point", "position": light.tolist(),
                        "intensity": [intensity] * 3}], rho=rho)
    img = render_buffer(sc, 256).mean()[..., 0]
    p = _pixel_points(sc, (24, 24))
    to_light = light - p
    r2 = (to_light**2).sum(-1)
    cos = to_light[..., 2] / np.sqrt(r2)
    expected = _box_filter(intensity * rho * cos / (math.pi * r2), 8)
    np.testing.assert_allclose(img, expected, rtol=0.01)


def test_directional_light_on_diffuse_plane():
    """L = E·ρ·cosθ/π, the same at every point: no randomness at all, so 1e-9 relative."""
    irradiance, rho = 3.0, 0.8
    direction = np.array([0.3, -0.2, -1.0])
    sc = _plane_scene([{"type": "directional", "direction": direction.tolist(),
                        "irradiance": [irradiance] * 3}], rho=rho)
    buf = render_buffer(sc, 4)
    img = buf.sum / buf.count[..., None]  # float64: mean() rounds to float32
    cos = -direction[2] / np.linalg.norm(direction)
    np.testing.assert_allclose(img, irradiance * rho * cos / math.pi, rtol=1e-9)


def _slab_scene(ior, sigma, thickness):
    # A wide slab between z = −d/2 and z = d/2, seen head-on through a 1° field of view
    return scene([{"type": "box", "min": [-20, -20, -thickness / 2],
                   "max": [20, 20, thickness / 2], "material": "glass"}],
                 {"glass": {"type": "dielectric", "ior": ior, "absorption": list(sigma)}},
                 background=(1, 1, 1),
                 camera={"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 1},
                 film=(8, 8), spp=1024, max_depth=-1)


def test_beer_lambert_index_matched_slab():
    """At ior 1 there is no reflection: the slab transmits exp(−σa·d) of the background, exactly
    (every sample takes the same path, so the tolerance is rounding: 1e-9 relative)."""
    sigma, d = np.array([0.1, 0.7, 2.0]), 0.8
    img = render_buffer(_slab_scene(1.0, sigma, d), 4).mean()
    # The ray crosses at up to 0.5° off the normal: path length d/cos(0.5°) differs by 4e-5
    np.testing.assert_allclose(img, np.broadcast_to(np.exp(-sigma * d), img.shape), rtol=1e-4)


def test_slab_with_fresnel_and_absorption():
    """A glass slab (n = 1.5) in a uniform background, seen at normal incidence, returns
    R_slab + T_slab with incoherent multiple reflections (e.g. Born & Wolf §7.6; with a = e^{−σd}):
      T_slab = (1−R)²·a / (1 − R²a²),  R_slab = R + (1−R)²·R·a² / (1 − R²a²),  R = ((n−1)/(n+1))².
    This checks Fresnel at normal incidence, Beer–Lambert, the η² radiance scaling (which must
    cancel on the way out) and that roulette does not bias long internal bounce chains.
    Tolerance: 6 standard errors of the frame mean.
    """
    n, d = 1.5, 0.5
    sigma = np.array([0.0, 0.5, 3.0])
    buf = render_buffer(_slab_scene(n, sigma, d))
    r = ((n - 1) / (n + 1)) ** 2
    a = np.exp(-sigma * d)
    t_slab = (1 - r) ** 2 * a / (1 - r**2 * a**2)
    r_slab = r + (1 - r) ** 2 * r * a**2 / (1 - r**2 * a**2)
    expected = t_slab + r_slab
    var = buf.variance_of_mean()
    got = buf.mean().reshape(-1, 3).mean(axis=0)
    se = np.sqrt(var.reshape(-1, 3).sum(axis=0)) / 64
    assert np.all(np.abs(got - expected) < 6 * se + 1e-9), (got, expected, se)
    assert abs(got[0] - 1.0) < 6 * se[0] + 1e-9  # no absorption: energy is conserved


def test_max_depth_zero_shows_only_emitters():
    sc = scene([{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "d",
                 "emission": [2, 3, 4]}],
               {"d": {"type": "diffuse", "albedo": [0.9, 0.9, 0.9]}},
               lights=[{"type": "point", "position": [0, 3, 3], "intensity": [50, 50, 50]}],
               background=(0.5, 0.5, 0.5), max_depth=0, spp=4)
    img = render_buffer(sc).mean()
    np.testing.assert_array_equal(img[12, 16], np.float32([2, 3, 4]))
    np.testing.assert_array_equal(img[0, 0], np.float32([0.5, 0.5, 0.5]))


def test_non_finite_samples_are_dropped_and_counted():
    """Radiance that overflows to inf is left out of the pixel and counted, never added.

    (1e308 also overflows float32, so the check is on the float64 sums, not on mean().)
    """
    sc = scene([{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "d"}],
               {"d": {"type": "diffuse", "albedo": [1, 1, 1]}}, background=(1e308, 1e308, 1e308),
               spp=8)
    buf = render_buffer(sc)
    assert buf.total_dropped > 0
    assert np.all(np.isfinite(buf.sum)) and np.all(np.isfinite(buf.sum_sq))
    assert np.all(buf.count + buf.dropped == 8)
