"""Shading normals (renderer/materials/shading.py): the bent normal's guarantees, the folded lobe's
sampling against its density (chi²), its weights, no light through the surface, and the white
furnace at 1 on a smooth-shaded sphere."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.geometry.meshgen import uv_sphere
from renderer.materials.bsdf import DIFFUSE, PHONG, ROUGH_CONDUCTOR
from renderer.materials.shading import (
    BEND_EPSILON,
    bent_normal,
    shaded_eval,
    shaded_pdf,
    shaded_sample,
)
from renderer.render import render
from renderer.scene import load_scene
from tests.conftest import chi2_directions

NG = (0.0, 0.0, 1.0)


def unit(v) -> tuple[float, float, float]:
    v = np.asarray(v, np.float64)
    return tuple(v / np.linalg.norm(v))


def test_the_bent_normal_keeps_the_view_and_its_mirror_above_the_surface(rng):
    """Keller et al. 2017: after bending, wo is in the shading normal's hemisphere and wo's
    mirror direction about it lies at least BEND_EPSILON above the geometric surface."""
    for _ in range(2000):
        wo = unit(rng.normal(size=3) * [1, 1, 0.3] + [0, 0, 0.05])
        if wo[2] <= 1e-3:
            continue
        ns = unit(rng.normal(size=3) + [0, 0, 0.5])
        if ns[2] <= 0.0:
            continue
        b = np.array(bent_normal(wo, NG, ns))
        assert abs(np.linalg.norm(b) - 1.0) < 1e-12
        c = float(np.dot(wo, b))
        r = 2.0 * c * b - np.array(wo)
        assert c > 0.0 and r[2] >= BEND_EPSILON - 1e-9, (wo, ns, b)
        if (2.0 * np.dot(wo, ns) * np.array(ns) - wo)[2] >= BEND_EPSILON:
            assert tuple(b) == ns  # left alone where it needs no bending


ROWS = {DIFFUSE: np.array([1.0, 1.0, 1.0] + [0.0] * 20),
        PHONG: np.array([0.5, 0.5, 0.5, 0.4, 0.4, 0.4, 20.0] + [0.0] * 16),
        ROUGH_CONDUCTOR: np.array([0.2, 0.4, 1.4, 3.6, 2.5, 2.2, 1, 1, 1, 0.3] + [0.0] * 13)}
CASES = [(DIFFUSE, 70.0, 60.0), (DIFFUSE, 20.0, 35.0), (PHONG, 50.0, 40.0),
         (ROUGH_CONDUCTOR, 40.0, 45.0)]


def case(theta_o, tilt):
    """wo at theta_o from the geometric normal, the shading normal tilted by ``tilt`` away from
    it (towards −x, so that wo, on the +x side, is near or below its horizon)."""
    t, s = math.radians(theta_o), math.radians(tilt)
    wo = (math.sin(t), 0.0, math.cos(t))
    ns = (-math.sin(s), 0.0, math.cos(s))
    return wo, bent_normal(wo, NG, ns)


@pytest.mark.parametrize("kind, theta_o, tilt", CASES)
def test_folded_sampling_follows_its_pdf(rng, kind, theta_o, tilt):
    wo, ns = case(theta_o, tilt)
    row = ROWS[kind]

    def sampler(n):
        out = np.full((n, 3), np.nan)
        for k, (uc, u1, u2) in enumerate(rng.random((n, 3))):
            wi, _, _, ok = shaded_sample(kind, row, wo, NG, ns, uc, u1, u2)
            if ok:
                out[k] = wi
        return out

    def pdf(w):
        return np.array([shaded_pdf(kind, row, wo, tuple(x), NG, ns) for x in w])

    chi2_directions(sampler, pdf, 30_000, n_cos=12, n_phi=24, sub=6,
                    what=f"kind {kind} wo {theta_o} tilt {tilt}")


@pytest.mark.parametrize("kind, theta_o, tilt", CASES)
def test_no_direction_below_the_surface_and_weights_are_eval_over_pdf(rng, kind, theta_o, tilt):
    wo, ns = case(theta_o, tilt)
    row = ROWS[kind]
    for uc, u1, u2 in rng.random((300, 3)):
        wi, w, pdf, ok = shaded_sample(kind, row, wo, NG, ns, uc, u1, u2)
        if not ok:
            continue
        assert wi[2] > 0.0  # no leak: above the geometric surface
        f = shaded_eval(kind, row, wo, wi, NG, ns)
        np.testing.assert_allclose(w, np.array(f) / pdf, rtol=1e-9)
        below = (wi[0], wi[1], -wi[2])
        assert shaded_eval(kind, row, wo, below, NG, ns) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("theta_o, tilt", [(70.0, 60.0), (85.0, 30.0), (10.0, 45.0)])
def test_a_white_diffuse_lobe_reflects_everything(rng, theta_o, tilt):
    """Folding keeps the lobe's albedo: every sample of a white Lambertian weighs exactly 1
    (where dropping the directions below the surface would lose up to half)."""
    wo, ns = case(theta_o, tilt)
    for uc, u1, u2 in rng.random((300, 3)):
        wi, w, pdf, ok = shaded_sample(DIFFUSE, ROWS[DIFFUSE], wo, NG, ns, uc, u1, u2)
        assert ok and w == pytest.approx((1.0, 1.0, 1.0), rel=1e-12)


def sphere_scene(material: dict, normals, background=(1.0, 1.0, 1.0), lights=()) -> dict:
    vertices, triangles, radial, _ = uv_sphere(12, 8)
    mesh = {"type": "mesh", "vertices": vertices.tolist(), "triangles": triangles.tolist(),
            "material": "m"}
    if normals is not None:
        mesh["normals"] = (radial if isinstance(normals, str) else normals).tolist()
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 32},
        "film": {"width": 24, "height": 24},
        "render": {"spp": 32, "max_depth": -1, "seed": 5},
        "background": list(background),
        "materials": {"m": material},
        "objects": [mesh],
        "lights": list(lights),
    }


@pytest.mark.parametrize("normals", ["smooth", "noisy"])
def test_white_furnace_with_shading_normals(rng, normals):
    """A white diffuse sphere (a coarse mesh, 12 × 8) under a uniform white sky, smooth-shaded
    or with normals tilted at random (±0.6 on unit normals): the image converges to 1 (the
    background's pixels are 1 exactly). Dropping the directions the lobe about a tilted normal
    sends below the surface, instead of folding them, loses energy at every bounce. Tolerance:
    4σ of the image mean's noise at 128 spp (σ ≈ 0.0009, from 256-spp renders whose sphere
    pixels spread by ±0.02; flat shading, smooth and noisy normals all measured 0.9994-0.9996)."""
    n = None
    if normals == "noisy":
        _, _, radial, _ = uv_sphere(12, 8)
        n = radial + 0.6 * rng.normal(size=radial.shape)
    scene = load_scene(sphere_scene({"type": "diffuse", "albedo": [1, 1, 1]},
                                    "smooth" if n is None else n))
    image = render(scene, 128, threads=2)
    assert image.mean() == pytest.approx(1.0, abs=4e-3)


def test_no_light_leaks_through_a_smooth_shaded_surface():
    """A point light inside a smooth-shaded closed sphere: outside, nothing is lit (the bent and
    folded lobes never send or take light across the geometric surface)."""
    scene = sphere_scene({"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}, "smooth",
                         background=(0.0, 0.0, 0.0),
                         lights=[{"type": "point", "position": [0, 0, 0.5],
                                  "intensity": [10, 10, 10]}])
    assert render(load_scene(scene), threads=1).max() == 0.0
