"""Rough coats on the approximate translucent methods (``translucent.roughness``; the volumetric
method's rough boundary is tests/renderer/materials/test_rough_translucent.py): the limit α → 0,
the white furnace, the coat's reflection against the GGX reflection albedo integrated by
quadrature, stability at α = 1, and the methods that refuse a rough boundary and why."""

import math

import numpy as np
import pytest

from renderer.materials.bsdf import (
    DIFFUSE_ENTRY,
    DIFFUSION,
    N_PARAMS,
    ROUGH_DIFFUSE_ENTRY,
    ROUGH_DIFFUSION,
    bsdf_eval,
    bsdf_sample,
)
from renderer.materials.translucent import BOUNDARY_ROUGHNESS, IOR
from renderer.render import render_buffer
from renderer.scene import SceneError, load_scene
from renderer.scene.compile import compile_scene

SIZE = 16
FOV = 30.0
DISTANCE = 4.0


def scene_with(wax: dict, background=(1.0, 1.0, 1.0), spp=64, lights=()) -> dict:
    return {
        "camera": {"position": [0, 0, DISTANCE], "look_at": [0, 0, 0], "fov": FOV},
        "film": {"width": SIZE, "height": SIZE},
        "render": {"spp": spp, "max_depth": -1, "seed": 3},
        "background": list(background),
        "lights": list(lights),
        "materials": {"wax": {"type": "translucent", "ior": 1.4} | wax},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "wax"}],
    }


def pixel_mean_and_se(buf):
    mean = buf.sum / buf.count[..., None]
    return mean, np.sqrt(buf.variance_of_mean())


def block_mean_and_se(buf, lo=4, hi=12):
    var = buf.variance_of_mean()[lo:hi, lo:hi]
    mean = (buf.sum[lo:hi, lo:hi] / buf.count[lo:hi, lo:hi, None]).mean(axis=(0, 1))
    return mean, np.sqrt(var.sum(axis=(0, 1))) / var[..., 0].size


# --- The scene rules --------------------------------------------------------------------------


@pytest.mark.parametrize("method, smooth, rough", [
    ("diffuse_entry", DIFFUSE_ENTRY, ROUGH_DIFFUSE_ENTRY),
    ("diffusion", DIFFUSION, ROUGH_DIFFUSION)])
def test_kinds_compiled_for_a_rough_coat(method, smooth, rough):
    def kind(wax):
        return int(compile_scene(load_scene(scene_with(wax))).arrays.mat_kind[0])

    assert kind({"method": method, "roughness": 0.3}) == rough
    assert kind({"method": method, "roughness": 0.0}) == smooth
    # index-matched: no boundary to roughen, the smooth kind's straight entry
    assert kind({"method": method, "roughness": 0.3, "ior": 1.0}) == smooth


@pytest.mark.parametrize("method", ["single_scatter", "backlight"])
def test_methods_without_a_dielectric_boundary_refuse_roughness(method):
    with pytest.raises(SceneError) as info:
        load_scene(scene_with({"method": method, "roughness": 0.3}))
    (field, message), = info.value.errors
    assert field == "materials.wax"
    assert message.startswith("roughness (a rough boundary) is rendered by methods ")
    assert f"method {method!r} has no dielectric boundary to roughen" in message


@pytest.mark.parametrize("knob, value", [("specular_exponent", 50.0), ("direct_light", True)])
def test_diffuse_entry_refuses_roughness_with_a_knob_of_the_smooth_coat(knob, value):
    with pytest.raises(SceneError) as info:
        load_scene(scene_with({"method": "diffuse_entry", "roughness": 0.3, knob: value}))
    (field, message), = info.value.errors
    assert field == "materials.wax"
    assert message.startswith(f"{knob} and roughness cannot be combined")


# --- diffuse_entry behind a rough coat ------------------------------------------------------


LIGHTS = ({"type": "point", "position": [3.0, 2.0, 3.0], "intensity": [20.0, 20.0, 20.0]},)


@pytest.mark.parametrize("method", ["diffuse_entry", "diffusion"])
def test_a_nearly_smooth_coat_renders_as_the_smooth_one(method):
    """α = 1e-3 against α = 0 (a point light and a grey sky, a coloured medium): every pixel's
    mean within 5 standard errors of the difference, and the image means within 2 %. The rough
    coat's reflection and entry converge to the smooth coat's as α → 0; a wrong weight
    (a missing 1/η², the entry not scattered, the reflection counted twice by the light sample
    and the BSDF) would differ by far more."""
    wax = {"method": method, "albedo": [0.9, 0.6, 0.3], "density": 3.0}
    smooth = render_buffer(load_scene(scene_with(wax, (0.5, 0.5, 0.5), 256, LIGHTS)))
    rough = render_buffer(load_scene(scene_with(wax | {"roughness": 1e-3}, (0.5, 0.5, 0.5), 256,
                                                LIGHTS)))
    m0, s0 = pixel_mean_and_se(smooth)
    m1, s1 = pixel_mean_and_se(rough)
    z = np.abs(m1 - m0) / np.sqrt(s0 ** 2 + s1 ** 2 + 1e-12)
    assert (z < 5.0).all(), (z.max(), np.unravel_index(z.argmax(), z.shape))
    assert np.allclose(m1.mean(axis=(0, 1)), m0.mean(axis=(0, 1)), rtol=0.02)


@pytest.mark.parametrize("method, density, tolerance", [("diffuse_entry", 2.0, 0.02),
                                                         ("diffusion", 200.0, 0.05)])
def test_a_white_furnace_through_a_rough_coat_makes_no_energy(method, density, tolerance):
    """A non-absorbing medium (albedo 1) behind a rough coat in a white furnace: never above 1
    (no energy from nowhere, 4 standard errors); the smooth coat's near-1 at α 0 (the method's
    own loss: diffusion's profile darkens where the medium is not semi-infinite, hence its dense
    medium here); and more is lost the rougher the coat: the single-scattering microfacet model
    drops the light that would bounce between microfacets, as volumetric's rough boundary and
    Mitsuba's roughdielectric do. Measured (16×16, 64 spp): diffuse_entry 0.998, 0.958, 0.672,
    at α 0, 0.05, 0.3 (volumetric's rough boundary 1.000, 0.981, 0.764: a walk that scatters at
    entry meets the boundary from inside more often); diffusion at density 200 0.976, 0.960,
    0.946, 0.845 at α 0, 0.05, 0.3, 1."""
    means, ses = [], []
    for alpha in (0.0, 0.05, 0.3, 1.0):
        wax = {"method": method, "albedo": [1.0, 1.0, 1.0], "density": density,
               "roughness": alpha}
        mean, se = block_mean_and_se(render_buffer(load_scene(scene_with(wax))))
        assert (mean < 1.0 + 4 * se).all(), (alpha, mean, se)
        means.append(mean[0])
        ses.append(se[0])
    assert abs(means[0] - 1.0) < tolerance + 4 * ses[0], means
    assert means[3] < means[0] - 4 * math.hypot(ses[0], ses[3]) and means[3] > 0.2, means
    if method == "diffuse_entry":
        assert means[0] > means[1] > means[2] > means[3], means


@pytest.mark.parametrize("kind", [ROUGH_DIFFUSE_ENTRY, ROUGH_DIFFUSION])
@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_the_coat_reflects_and_transmits_no_more_than_arrives(rng, alpha, kind):
    """The rough coat's sample (bsdf_sample of ROUGH_DIFFUSE_ENTRY) from outside and from inside
    at several angles: the mean reflected weight plus the mean transmitted energy (the weight
    with radiance's (η_i/η_t)² undone) is at most 1 (2000 samples: 3 standard errors); from
    outside the reflected part is the GGX reflection albedo of the quadrature below (within
    3 standard errors + 0.003), and the coat's value for a direction that enters is 0 (what
    enters is scattered at once: no straight path to a light)."""
    ior = 1.4
    row = np.zeros(N_PARAMS)
    row[IOR], row[BOUNDARY_ROUGHNESS] = ior, alpha
    n = (0.0, 0.0, 1.0)
    for theta in (0.0, 30.0, 60.0, 85.0, 120.0, 170.0):
        wo = (math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta)))
        outside = wo[2] > 0.0
        refl, energy = [], []
        for u in rng.random((2000, 3)):
            wi, w, pdf, ok = bsdf_sample(kind, row, wo, n, *u)
            r = t = 0.0
            if ok:
                assert np.isfinite(w[0]) and pdf > 0.0
                if (wi[2] > 0.0) == outside:
                    r = w[0]
                    value = bsdf_eval(kind, row, wo, wi, n)[0]
                    assert w[0] == pytest.approx(value / pdf, rel=1e-9)
                else:
                    t = w[0] * (ior * ior if outside else 1.0 / (ior * ior))
                    if outside:
                        assert bsdf_eval(kind, row, wo, wi, n)[0] == 0.0
            refl.append(r)
            energy.append(r + t)
        energy = np.asarray(energy)
        assert energy.mean() <= 1.0 + 3 * energy.std() / math.sqrt(energy.size), (theta, alpha)
        if outside:
            refl = np.asarray(refl)
            # (a glossy lobe at grazing angles needs the finer grid: at α 0.05 and 85° the
            # coarse one gives 0.302, 2000 × 1000 0.4240, 4000 × 2000 0.4253)
            grid = (600, 300) if alpha >= 0.1 else (2000, 1000)
            expected = ggx_reflection_albedo(wo[2], alpha, ior, *grid)
            assert abs(refl.mean() - expected) < 3 * refl.std() / math.sqrt(refl.size) + 0.003, (
                theta, alpha, refl.mean(), expected)


def ggx_reflection_albedo(cos_o, alpha, eta, n_theta=600, n_phi=300):
    """∫ f_r(wo, wi) cos θi dωi of the GGX rough dielectric's reflection (Walter et al. 2007;
    separable Smith G, exact unpolarized Fresnel at wo·h) by midpoint quadrature over the
    hemisphere, written apart from the renderer's kernels."""
    theta = (np.arange(n_theta) + 0.5) * (0.5 * math.pi / n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2.0 * math.pi / n_phi)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    wo = np.array([math.sqrt(max(0.0, 1.0 - cos_o ** 2)), 0.0, cos_o])
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    d = a2 / (math.pi * (h[..., 2] ** 2 * (a2 - 1.0) + 1.0) ** 2)

    def g1(c):
        tan2 = np.maximum(1.0 - c * c, 0.0) / (c * c)
        return 2.0 / (1.0 + np.sqrt(1.0 + a2 * tan2))

    c = np.abs(h @ wo)
    sin2_t = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    rs = ((c - eta * cos_t) / (c + eta * cos_t)) ** 2
    rp = ((eta * c - cos_t) / (eta * c + cos_t)) ** 2
    f = np.where(sin2_t >= 1.0, 1.0, 0.5 * (rs + rp))
    integrand = f * d * g1(cos_o) * g1(wi[..., 2]) / (4.0 * cos_o)
    dw = np.sin(th) * (0.5 * math.pi / n_theta) * (2.0 * math.pi / n_phi)
    return float((integrand * dw).sum())


def pixel_cosines(sub=4):
    """cos θo at sub × sub points of each pixel where the camera's ray meets the unit sphere
    (NaN off it): the same pinhole as renderer.integrators.path.camera_ray."""
    tan_half = math.tan(math.radians(FOV) / 2.0)
    offs = (np.arange(sub) + 0.5) / sub
    out = np.full((SIZE, SIZE, sub * sub), np.nan)
    for y in range(SIZE):
        for x in range(SIZE):
            k = 0
            for jy in offs:
                for jx in offs:
                    sx = (2.0 * (x + jx) / SIZE - 1.0) * tan_half
                    sy = (1.0 - 2.0 * (y + jy) / SIZE) * tan_half
                    d = np.array([sx, sy, -1.0])
                    d /= np.linalg.norm(d)
                    o = np.array([0.0, 0.0, DISTANCE])
                    b = o @ d
                    disc = b * b - (o @ o - 1.0)
                    if disc > 0.0:
                        t = -b - math.sqrt(disc)
                        p = o + t * d
                        out[y, x, k] = -(d @ p)
                    k += 1
    return out


@pytest.mark.parametrize("method", ["diffuse_entry", "diffusion"])
@pytest.mark.parametrize("alpha", [0.3, 1.0])
def test_the_rough_coat_reflects_the_ggx_reflection_albedo(alpha, method):
    """A black medium (albedo 0: whatever enters is absorbed at the entry scattering) behind a
    rough coat under a white sky: each pixel is the coat's directional reflectance, the GGX
    reflection albedo E_r(θo), integrated here by quadrature over the hemisphere and averaged
    over each pixel's points on the sphere. Pixels wholly on the sphere, within 4 standard
    errors + 0.002 (the quadrature's and the pixel average's error)."""
    wax = {"method": method, "albedo": [0.0, 0.0, 0.0], "density": 2.0,
           "roughness": alpha, "ior": 1.5}
    mean, se = pixel_mean_and_se(render_buffer(load_scene(scene_with(wax, spp=256))))
    cosines = pixel_cosines()
    table_mu = np.linspace(0.02, 1.0, 50)
    table = np.array([ggx_reflection_albedo(mu, alpha, 1.5) for mu in table_mu])
    checked = 0
    for y in range(SIZE):
        for x in range(SIZE):
            mus = cosines[y, x]
            if np.isnan(mus).any() or mus.min() < 0.1:
                continue
            expected = np.interp(mus, table_mu, table).mean()
            assert abs(mean[y, x, 0] - expected) < 4 * se[y, x, 0] + 0.002, (
                y, x, mean[y, x, 0], se[y, x, 0], expected)
            checked += 1
    assert checked > 100


def test_the_quadrature_matches_the_smooth_fresnel_in_the_limit():
    """The test's own quadrature: at small α the GGX reflection albedo is the smooth
    dielectric's Fresnel reflectance (normal incidence, η 1.5: 0.04)."""
    assert abs(ggx_reflection_albedo(1.0, 0.01, 1.5, 3000, 60) - 0.04) < 1e-3


@pytest.mark.parametrize("method", ["diffuse_entry", "diffusion"])
@pytest.mark.parametrize("density", [1e-3, 1e4])
def test_a_rough_coat_at_alpha_one_stays_finite(density, method):
    """The failure regime: α 1 over a nearly empty and a nearly opaque medium, albedo 0.999,
    lit by a point light and a sky: no NaN, no dropped sample, no energy from nowhere."""
    wax = {"method": method, "albedo": [0.999, 0.5, 0.0], "density": density,
           "roughness": 1.0}
    buf = render_buffer(load_scene(scene_with(wax, spp=32)))
    assert np.isfinite(buf.sum).all() and buf.dropped.sum() == 0
    mean, se = block_mean_and_se(buf)
    assert (mean < 1.0 + 4 * se).all(), (density, mean, se)
    lit = render_buffer(load_scene(scene_with(wax, (0.2, 0.2, 0.2), 32, LIGHTS)))
    assert np.isfinite(lit.sum).all() and lit.dropped.sum() == 0
