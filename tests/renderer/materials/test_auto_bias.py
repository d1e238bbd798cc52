"""``auto`` and ``render.target_error`` together: the bias of the model ``auto`` chose takes its
share of the target, and the loop aims the samples' noise at the rest (``frame_share``,
``frame_bias``, ``adaptive.noise_target``)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from renderer.film.adaptive import AIM, NOISE_FLOOR, STOP_SLACK, noise_target, stopping_error
from renderer.materials.auto import OPAQUE_ERROR, auto_choices, frame_bias, frame_share
from renderer.render import render_buffer
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[3]
# Dense wax (the opaque limit's worst case, docs/images/accuracy/opaque.csv): auto renders it as
# the opaque surface from all the views below
DENSE = {"method": "auto", "albedo": [0.99] * 3, "g": 0.5, "ior": 1.4, "density": 3000.0}


def dense_scene(position, target=0.01, width=64, height=48, look_at=(0.0, -0.5, 0.0)) -> dict:
    data = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    data["film"] = {"width": width, "height": height}
    data["camera"].update(position=list(position), look_at=list(look_at))
    data["render"].update(spp=4096, seed=3)
    if target is not None:
        data["render"]["target_error"] = target
    data["materials"]["wax"].update(DENSE)
    return data


def covered_share(scene) -> float:
    """The share of pixels whose centre ray hits the wax sphere: the render's pinhole camera
    (renderer.integrators.path.camera_ray) and the ray-sphere discriminant, per pixel."""
    cam, film = scene.camera, scene.film
    w, h = film.width, film.height
    pos = np.asarray(cam.position, float)
    f = np.asarray(cam.look_at, float) - pos
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(cam.up, float))
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    t = math.tan(math.radians(cam.fov) / 2)
    sx = (2.0 * (np.arange(w) + 0.5) / w - 1.0) * t * w / h
    sy = (1.0 - 2.0 * (np.arange(h) + 0.5) / h) * t
    d = f + sx[None, :, None] * r + sy[:, None, None] * u
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    hit = np.zeros((h, w), bool)
    for sphere in (o for o in scene.objects if o.material == "wax"):
        oc = pos - np.asarray(sphere.center, float)
        b = d @ oc
        disc = b * b - (oc @ oc - sphere.radius**2)
        hit |= (disc >= 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)
    return float(hit.mean())


@pytest.mark.parametrize("position", [(0.0, 0.0, 3.9), (0.0, -0.5, 2.4), (0.0, -0.5, 1.3),
                                      (0.7, 0.4, 1.8)])
@pytest.mark.parametrize("film", [(64, 48), (1600, 1200)])
def test_frame_share_bounds_the_pixels_a_sphere_covers_and_not_by_much(position, film):
    """The share of pixels that may see the sphere is at least the share whose centre ray hits
    it (a closed form per pixel), and at most that plus a band around its silhouette as wide as
    the widening, half a pixel's diagonal (on a film of 1.9 M pixels, one ray a block of 5×5:
    half the block's), and a pixel for the grid's steps."""
    scene = load_scene(dense_scene(position, width=film[0], height=film[1],
                                   look_at=(0.0, -0.5, 0.0) if position[0] == 0 else
                                   (0.0, 0.0, 0.0)))
    objects = [o for o in scene.objects if o.material == "wax"]
    share = frame_share(scene, objects)
    covered = covered_share(scene)
    assert covered > 0.01
    assert share >= covered
    # the silhouette's band: its perimeter (a circle of the covered area's radius, in pixels)
    # times the widening and a pixel
    pixels = film[0] * film[1]
    k = max(1, math.ceil(math.sqrt(pixels / 65536)))
    radius = math.sqrt(covered * pixels / math.pi)
    band = 2 * math.pi * radius * (math.sqrt(2) / 2 * k + 1) / pixels
    assert share <= covered + band, (share, covered, band)


def test_frame_share_with_many_objects_casts_fewer_rays_and_still_bounds_them(monkeypatch):
    """Past SHARE_TESTS ray-sphere tests the grid coarsens (here 40 small spheres and 3072
    pixels: 1024 rays, one a 2×2 block): still at least the pixels the spheres cover."""
    import renderer.materials.auto as auto

    data = dense_scene((0.0, 0.0, 3.9), look_at=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(5)
    data["objects"] += [{"type": "sphere", "center": rng.uniform(-0.9, 0.9, 3).tolist(),
                         "radius": 0.04, "material": "wax"} for _ in range(40)]
    scene = load_scene(data)
    objects = [o for o in scene.objects if o.material == "wax"]
    fine = frame_share(scene, objects)
    monkeypatch.setattr(auto, "SHARE_TESTS", 41 * 1024)
    coarse = frame_share(scene, objects)
    covered = covered_share(scene)
    assert covered <= fine < coarse


def test_frame_share_is_nothing_behind_the_camera_and_everything_inside():
    behind = load_scene(dense_scene((0.0, -0.5, 0.8), look_at=(0.0, -0.5, 2.0)))
    assert frame_share(behind, [o for o in behind.objects if o.material == "wax"]) == 0.0
    inside = load_scene(dense_scene((0.0, -0.5, 0.1), look_at=(0.0, -0.5, 2.0)))
    assert frame_share(inside, [o for o in inside.objects if o.material == "wax"]) == 1.0
    assert frame_share(inside, []) == 0.0


def test_frame_bias_is_each_biased_models_error_times_its_share_of_the_frame():
    """Σ expected_error × frame_share over auto's materials, at most the largest error; an
    unbiased choice (volumetric) and a method the scene names add nothing."""
    data = dense_scene((0.0, -0.5, 2.4))
    scene = load_scene(data)
    choices = auto_choices(scene)
    assert choices["wax"].method == "opaque" and choices["wax"].expected_error == OPAQUE_ERROR
    share = frame_share(scene, [o for o in scene.objects if o.material == "wax"])
    assert 0.0 < share < 0.5
    assert frame_bias(scene) == pytest.approx(OPAQUE_ERROR * share, rel=1e-12)
    # a second dense sphere of another auto material: the two add
    twin = json.loads(json.dumps(data))
    twin["materials"]["wax2"] = dict(twin["materials"]["wax"])
    twin["objects"].append({"type": "sphere", "center": [0.55, 0.3, -0.3], "radius": 0.25,
                            "material": "wax2"})
    two = load_scene(twin)
    share2 = frame_share(two, [o for o in two.objects if o.material == "wax2"])
    assert share2 > 0.0
    assert frame_bias(two) == pytest.approx(OPAQUE_ERROR * (share + share2), rel=1e-12)
    # ... at most the largest model's error, where the shares add past the whole frame
    close = load_scene(dense_scene((0.0, -0.5, 0.1), look_at=(0.0, -0.5, -2.0)))
    assert frame_bias(close) <= OPAQUE_ERROR
    # volumetric (a loose density: auto takes the reference at 0.01) and a named method: none
    loose = json.loads(json.dumps(data))
    loose["materials"]["wax"]["density"] = 8.0
    assert auto_choices(load_scene(loose))["wax"].method == "volumetric"
    assert frame_bias(load_scene(loose)) == 0.0
    named = json.loads(json.dumps(data))
    named["materials"]["wax"]["method"] = "diffusion"
    assert frame_bias(load_scene(named)) == 0.0


def test_noise_target_is_the_target_less_the_bias_and_never_below_its_floor():
    assert noise_target(0.01, 0.0) == 0.01
    assert noise_target(0.01, 0.004) == pytest.approx(0.006, rel=1e-12)
    assert noise_target(0.01, -1.0) == 0.01
    assert noise_target(0.01, 0.0095) == pytest.approx(NOISE_FLOOR * 0.01, rel=1e-12)
    assert noise_target(0.01, 0.02) == pytest.approx(NOISE_FLOOR * 0.01, rel=1e-12)


def test_compile_keeps_the_frames_bias_only_with_a_target():
    cs = compile_scene(load_scene(dense_scene((0.0, -0.5, 1.3))))
    assert cs.expected_bias == pytest.approx(frame_bias(load_scene(dense_scene((0.0, -0.5, 1.3)))))
    assert cs.expected_bias > 0.5 * OPAQUE_ERROR
    assert compile_scene(load_scene(dense_scene((0.0, -0.5, 1.3), None))).expected_bias == 0.0


def test_the_loop_aims_the_samples_noise_at_the_target_less_the_bias():
    """A close-up of dense wax that auto renders as the opaque surface at target 0.01: the
    sphere covers most of the frame, so the model's bias (up to 0.00847 on its pixels) takes
    most of the target. The loop stops where the samples' noise is within its slack of AIM ×
    (target − bias), not of AIM × target, and the noise and the bias together are within the
    target (the noise alone at AIM × target would leave the frame at 0.008 + 0.006)."""
    cs = compile_scene(load_scene(dense_scene((0.0, -0.5, 1.3))))
    bias = cs.expected_bias
    assert cs.info["auto"]["wax"]["method"] == "opaque"
    buf = render_buffer(cs)
    noise = stopping_error(buf)
    assert noise <= AIM * (0.01 - bias) * (1.0 + STOP_SLACK)
    assert noise + bias <= 0.01
    # the aim ignoring the bias stops far earlier, with the frame above the target
    loose = render_buffer(dataclasses.replace(cs, expected_bias=0.0))
    assert stopping_error(loose) > AIM * (0.01 - bias) * 1.5
    assert buf.count.sum() > 2 * loose.count.sum()
