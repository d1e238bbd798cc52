"""The translucent methods against published values, closed forms and their failure regimes.

The probes are slabs rendered through the ordinary renderer, so they exercise exactly the
free-flight, phase-function and boundary code that images use. A camera with a 1° field of view
looks at a wide slab along its normal. By reciprocity, the radiance it sees under a uniform
background of radiance 1 equals the slab's total reflectance for light arriving along the normal;
a black plane just below the slab removes the light coming from the other side, so what remains is
the reflectance alone. Without the plane, the camera sees reflectance plus total transmittance.

Tolerances: three standard errors of the estimate (as the issue asks), with the standard error from
the sample buffer's own variance estimate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.geometry.meshgen import torus
from renderer.render import render_buffer
from renderer.scene import load_scene


def slab_probe(*, ior, albedo, g, tau, thickness=1.0, black_below=True, spp=1024, seed=1,
               method="volumetric", knobs=None):
    objects = [{"type": "box", "min": [-50, -50, -thickness / 2], "max": [50, 50, thickness / 2],
                "material": "medium"}]
    if black_below:
        objects.append({"type": "quad", "origin": [-1000, -1000, -thickness / 2 - 0.01],
                        "edge1": [2000, 0, 0], "edge2": [0, 2000, 0], "material": "black"})
    scene = load_scene({
        "camera": {"position": [0, 0, thickness / 2 + 5], "look_at": [0, 0, 0], "fov": 1},
        "film": {"width": 8, "height": 8},
        "render": {"spp": spp, "max_depth": -1, "seed": seed},
        "background": [1, 1, 1],
        "materials": {
            "medium": {"type": "translucent", "method": method, "ior": ior,
                       "albedo": [albedo] * 3, "density": tau / thickness, "g": g} | (knobs or {}),
            "black": {"type": "diffuse", "albedo": [0, 0, 0]},
        },
        "objects": objects,
    })
    buf = render_buffer(scene)
    mean = buf.sum[..., 0].sum() / buf.count.sum()
    se = math.sqrt(buf.variance_of_mean()[..., 0].sum()) / buf.count.size
    return mean, se


def test_van_de_hulst_slab_reflectance():
    """van de Hulst (1980), slab of optical thickness 2, albedo 0.9, g 0.75, n 1, normal
    incidence: total diffuse reflectance 0.09739 (as tabulated in Prahl's thesis and MCML)."""
    r, se = slab_probe(ior=1.0, albedo=0.9, g=0.75, tau=2.0)
    assert abs(r - 0.09739) < 3 * se, (r, se)


def test_van_de_hulst_slab_reflectance_plus_transmittance():
    """Same slab with light from both sides: R + T = 0.09739 + 0.66096 (T includes the
    unscattered part)."""
    rt, se = slab_probe(ior=1.0, albedo=0.9, g=0.75, tau=2.0, black_below=False)
    assert abs(rt - (0.09739 + 0.66096)) < 3 * se, (rt, se)


@pytest.mark.slow
def test_giovanelli_semi_infinite_mismatched_boundary():
    """Giovanelli (1955), semi-infinite medium, n = 1.5, albedo 0.9, g 0: total reflectance 0.2600
    including the 4 % specular part (MCML, Wang et al. 1995, Table 2). A slab 100 mean free paths
    thick is semi-infinite here: the diffusion length at albedo 0.9 is ~2 mean free paths."""
    r, se = slab_probe(ior=1.5, albedo=0.9, g=0.0, tau=100.0, thickness=10.0, spp=4096)
    assert abs(r - 0.2600) < 3 * se, (r, se)


def torus_mesh(major=0.7, minor=0.3, n_major=24, n_minor=12):
    """A closed torus facing the camera: a concave mesh (it sees itself through its hole)."""
    vertices, triangles = torus(major, minor, n_major, n_minor, axis="z")
    return vertices.tolist(), triangles.tolist()


def furnace(*, ior, g, albedo=1.0, density=5.0, spp=64, shape="sphere", seed=2,
            method="volumetric"):
    if shape == "sphere":
        obj = {"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}
    elif shape == "shell":
        obj = {"type": "box", "min": [-1, -1, -0.001], "max": [1, 1, 0.001],
               "rotate": {"axis": [1, 1, 0], "angle": 30}, "material": "m"}
    else:
        vertices, triangles = torus_mesh()
        obj = {"type": "mesh", "vertices": vertices, "triangles": triangles, "material": "m"}
    scene = load_scene({
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": 16, "height": 16},
        "render": {"spp": spp, "max_depth": -1, "seed": seed},
        "background": [1, 1, 1],
        "materials": {"m": {"type": "translucent", "method": method, "ior": ior,
                            "albedo": [albedo] * 3, "density": density, "g": g}},
        "objects": [obj],
    })
    return render_buffer(scene)


@pytest.mark.parametrize("ior", [1.0, 1.5])
@pytest.mark.parametrize("g", [0.0, 0.9, -0.7])
def test_white_furnace(ior, g):
    """A closed object with albedo 1 under a uniform background of radiance 1 renders 1 everywhere:
    nothing is absorbed, whatever the boundary and the phase function. The mean over the object's
    pixels (the central 8×8) must be 1 within 6 standard errors. (Single pixels are not tested:
    at 64 spp roulette's rare large weights make a pixel's own variance estimate unreliable.)"""
    buf = furnace(ior=ior, g=g, spp=128)
    var = buf.variance_of_mean()[4:12, 4:12, 0]
    mean = (buf.sum[4:12, 4:12, 0] / buf.count[4:12, 4:12]).mean()
    se = math.sqrt(var.sum()) / var.size
    assert abs(mean - 1.0) < 6 * se + 1e-9, (mean, se)


STABILITY = {
    "density→0": dict(density=1e-6),
    "density→1e6": dict(density=1e6, spp=8),
    "albedo 0": dict(albedo=0.0),
    "g 0.99": dict(g=0.99),
    "g -0.99": dict(g=-0.99),
    "ior 2.5": dict(ior=2.5),
    "thin shell": dict(shape="shell", density=50.0),
    "albedo 1": dict(albedo=1.0),
    "ior 1": dict(ior=1.0),
    "concave mesh": dict(shape="torus", density=8.0),
}


@pytest.mark.parametrize(
    "method", ["volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion"])
@pytest.mark.parametrize("case", list(STABILITY))
def test_stability_in_failure_regimes(case, method):
    """Where the random walk is pushed to its limits it must still give finite, non-negative
    pixels, no energy above the furnace bound (albedo ≤ 1, background 1: the object's mean ≤ 1
    within 6 standard errors) and end (roulette bounds the path length; a hang would time the
    test out)."""
    params = {"ior": 1.3, "g": 0.0, "albedo": 0.99, "method": method} | STABILITY[case]
    buf = furnace(**params)
    assert buf.total_dropped == 0
    pixel = buf.sum / np.maximum(buf.count, 1)[..., None]
    assert np.all(np.isfinite(pixel)) and np.all(pixel >= 0)
    var = buf.variance_of_mean()[4:12, 4:12]
    mean = pixel[4:12, 4:12].mean()
    assert mean - 1.0 < 6 * math.sqrt(var.sum()) / var.size + 1e-9, case


@pytest.mark.parametrize(
    "method", ["volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion"])
def test_light_and_camera_inside_the_object_stay_finite(method):
    """An emitter inside a translucent sphere, and the camera inside it too: finite and
    non-negative for every method. Only the random walks carry the glow out (> 0.01); the
    approximations cannot (backlight and diffusion shade the outer surface only, single scattering
    loses what scatters twice), which their pages document as a failure mode."""
    def scene(camera_z):
        return load_scene({
            "camera": {"position": [0, 0, camera_z], "look_at": [0, 0, 0], "fov": 40},
            "film": {"width": 12, "height": 12},
            "render": {"spp": 32, "max_depth": -1, "seed": 1},
            "materials": {"wax": {"type": "translucent", "method": method, "ior": 1.4,
                                  "albedo": [0.95, 0.9, 0.8], "density": 4.0, "g": 0.2},
                          "lamp": {"type": "diffuse", "albedo": [0, 0, 0]}},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "wax"},
                        {"type": "sphere", "center": [0, 0, 0], "radius": 0.2, "material": "lamp",
                         "emission": [5, 5, 5]}],
            "lights": [{"type": "point", "position": [0, 0, 0.5], "intensity": [1, 1, 1]}],
        })
    outside = render_buffer(scene(4.0))
    inside = render_buffer(scene(0.6))
    for buf in (outside, inside):
        assert buf.total_dropped == 0
        assert np.all(np.isfinite(buf.sum)) and np.all(buf.sum >= 0)
    if method in ("volumetric", "diffuse_entry"):
        assert outside.mean().mean() > 0.01


@pytest.mark.parametrize("albedo", [0.5, 0.9, 1.0])
def test_single_scatter_matches_the_analytic_single_scattering_reflectance(albedo):
    """With every hit going in (surface_fraction 0), the single_scatter method is exactly the
    single-scattering term. For a semi-infinite isotropic medium at normal incidence, n = 1:
    R₁ = (a/2)(1 − ln 2) (van de Hulst; Prahl's thesis, eq. 3.12)."""
    r, se = slab_probe(method="single_scatter", knobs={"surface_fraction": 0.0}, ior=1.0,
                       albedo=albedo, g=0.0, tau=100.0, thickness=10.0)
    assert abs(r - albedo / 2 * (1 - math.log(2))) < 3 * se, (r, se)


def test_single_scatter_surface_fraction_mixes_lambert_and_single_scattering():
    """The seed paper's default: 80 % of hits scatter as a Lambertian surface of albedo a (whose
    reflectance under uniform light is a), 20 % go in: R = 0.8·a + 0.2·R₁."""
    a = 0.9
    r, se = slab_probe(method="single_scatter", ior=1.0, albedo=a, g=0.0, tau=100.0,
                       thickness=10.0)
    assert abs(r - (0.8 * a + 0.2 * a / 2 * (1 - math.log(2)))) < 3 * se, (r, se)


@pytest.mark.parametrize("knobs", [{}, {"specular_exponent": 50.0}])
def test_diffuse_entry_conserves_energy(knobs):
    """diffuse_entry at albedo 1 is lossless like the random walk it starts (a slab lit from both
    sides by a uniform background returns exactly 1): within 6 standard errors."""
    r, se = slab_probe(method="diffuse_entry", knobs=knobs, ior=1.4, albedo=1.0, g=0.3, tau=5.0,
                       black_below=False, spp=512)
    assert abs(r - 1.0) < 6 * se, (r, se)


def test_diffuse_entry_direct_light_stays_below_the_furnace_bound():
    """The separate direct-light estimate replaces, not adds to, the light the walk carries straight
    out to a light: under a uniform background the slab stays ≤ 1."""
    r, se = slab_probe(method="diffuse_entry", knobs={"direct_light": True}, ior=1.4, albedo=1.0,
                       g=0.3, tau=5.0, black_below=False, spp=512)
    assert r < 1.0 + 6 * se, (r, se)
    assert r > 0.5


def test_method_knobs_belong_to_their_method():
    with pytest.raises(Exception, match="surface_fraction applies to method 'single_scatter'"):
        slab_probe(method="volumetric", knobs={"surface_fraction": 0.5}, ior=1.0, albedo=0.5,
                   g=0.0, tau=1.0)


def test_backlight_matches_its_model_for_a_light_straight_behind():
    """A slab of thickness d lit from straight behind by a directional light E and seen head-on:
    the backlight method's documented model gives L = albedo·E·scale·(power + 1)/(2π)·
    e^{−σ_eff·d}, σ_eff = √(3σa(σa + σs(1 − g))), at distortion 0 (the lobe's axis is then the
    view direction through the slab). No randomness is left but the pixel jitter: 1e-6."""
    albedo, density, g, d, e = np.array([0.9, 0.7, 0.5]), 4.0, 0.3, 0.25, 2.0
    scene = load_scene({
        "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 0.5},
        "film": {"width": 4, "height": 4},
        "render": {"spp": 4, "max_depth": 1},
        "materials": {"m": {"type": "translucent", "method": "backlight", "ior": 1.0,
                            "albedo": albedo.tolist(), "density": density, "g": g,
                            "distortion": 0.0, "power": 6.0, "scale": 0.7}},
        "objects": [{"type": "box", "min": [-20, -20, -d / 2], "max": [20, 20, d / 2],
                     "material": "m"}],
        "lights": [{"type": "directional", "direction": [0, 0, 1], "irradiance": [e] * 3}],
    })
    buf = render_buffer(scene)
    img = buf.sum / buf.count[..., None]
    sigma_a = density * (1 - albedo)
    sigma_eff = np.sqrt(3 * sigma_a * (sigma_a + density * albedo * (1 - g)))
    expected = albedo * e * 0.7 * 7.0 / (2 * math.pi) * np.exp(-sigma_eff * d)
    # rays through the 0.5° field of view cross the slab up to 0.25° off its normal
    np.testing.assert_allclose(img, np.broadcast_to(expected, img.shape), rtol=1e-4)


def test_backlight_does_not_add_energy_under_a_uniform_background():
    """The lobe is normalized and the surface reflects only (1 − scale)·albedo, so a white slab lit
    from all sides stays below 1 (the GDC formula, unnormalized, would exceed it)."""
    for scale in (0.0, 0.5, 1.0):
        r, se = slab_probe(method="backlight", knobs={"scale": scale, "power": 1.0}, ior=1.0,
                           albedo=1.0, g=0.0, tau=0.1, thickness=0.2, black_below=False, spp=256)
        assert r < 1.0 + 6 * se, (scale, r, se)


def test_diffusion_matches_its_model_on_a_semi_infinite_medium():
    """On a flat semi-infinite medium the separable BSSRDF integrates in closed form: the view
    straight down under a uniform background sees F(0) + (1 − F(0))·A·(1 − 2F̄₁(η))/c, with A the
    dipole albedo, F̄₁ the first Fresnel moment (integrated here from the exact Fresnel equations)
    and c the S_w normalization. This checks the probe rays (tangent probes miss a plane and the
    MIS density must make up for it), the profile's normalization and S_w, to 3 standard errors.
    (Against Giovanelli's exact 0.2600 the model gives 0.30: the dipole's known bias at a
    mismatched boundary, documented in docs/methods/diffusion.md.)"""
    from scipy.integrate import quad

    from renderer.materials.diffusion import diffusion_parameters
    from renderer.materials.fresnel import fresnel_dielectric

    big_a, _, c = diffusion_parameters([0.9] * 3, 10.0, 0.0, 1.5)
    fm1 = quad(lambda mu: fresnel_dielectric(mu, 1.5)[0] * mu, 0, 1)[0]
    f0 = fresnel_dielectric(1.0, 1.5)[0]
    expected = f0 + (1 - f0) * big_a[0] * (1 - 2 * fm1) / c
    r, se = slab_probe(method="diffusion", ior=1.5, albedo=0.9, g=0.0, tau=100.0,
                       thickness=10.0, spp=512)
    assert abs(r - expected) < 3 * se, (r, expected, se)
