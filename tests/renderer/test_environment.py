"""The environment light: its sampler against its density (chi²), the density's normalization,
the lookup's orientation (against Mitsuba 3's envmap and by rendering), and what the light
delivers through the path tracer (furnaces).

Tolerances: N = 200 000 samples put the chi² test's power on cells of about 5 % error; the
furnace images are means over ~1000 pixels × 64 spp whose standard error is below 0.2 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from renderer.environment import (
    build_environment,
    cell_weights,
    direction_to_uv,
    environment_pdf,
    environment_radiance,
    environment_sample,
)
from renderer.film.image_io import encode_pfm
from renderer.geometry.transform import rotation_matrix
from renderer.jit import alloc_kernel
from renderer.render import render
from renderer.scene import load_scene

N = 200_000


def sky_image(h: int = 12, w: int = 24) -> np.ndarray:
    """A small sky: a bright sun off-centre, a gradient, a black ground row and black texels."""
    y, x = np.mgrid[0:h, 0:w]
    img = np.zeros((h, w, 3), np.float32)
    img[..., 0] = 0.2 + 0.8 * (h - 1 - y) / (h - 1)
    img[..., 1] = 0.3 + 0.1 * np.sin(2 * np.pi * x / w)
    img[..., 2] = 1.0 - 0.5 * y / (h - 1)
    img[h - 1] = 0.0  # the ground pole: black
    img[h // 2 + 1 :, : w // 4] = 0.0  # a black patch that touches the seam
    img[3, 17] = (400.0, 380.0, 300.0)  # the sun: one texel
    return img


@alloc_kernel
def _sample_many(image, marginal, conditional, rot, u):
    m = u.shape[0]
    wi = np.empty((m, 3))
    le = np.empty((m, 3))
    pdf = np.empty(m)
    for i in range(m):
        w, radiance, p = environment_sample(image, marginal, conditional, rot, u[i, 0], u[i, 1])
        for j in range(3):
            wi[i, j] = w[j] if p > 0.0 else np.nan
            le[i, j] = radiance[j]
        pdf[i] = p
    return wi, le, pdf


@alloc_kernel
def _pdf_many(image, marginal, conditional, rot, d):
    out = np.empty(d.shape[0])
    for i in range(d.shape[0]):
        out[i] = environment_pdf(image, marginal, conditional, rot, (d[i, 0], d[i, 1], d[i, 2]))
    return out


@alloc_kernel
def _radiance_many(image, rot, d):
    out = np.empty((d.shape[0], 3))
    for i in range(d.shape[0]):
        u, v, _ = direction_to_uv(rot, (d[i, 0], d[i, 1], d[i, 2]))
        r, g, b = environment_radiance(image, u, v)
        out[i, 0], out[i, 1], out[i, 2] = r, g, b
    return out


def uniform_directions(rng, n: int) -> np.ndarray:
    z = 1.0 - 2.0 * rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


ROTATIONS = {"identity": np.eye(3), "tilted": rotation_matrix((1.0, 2.0, 0.5), 37.0)}


@pytest.fixture(params=list(ROTATIONS))
def env(request):
    image, marginal, conditional, rot, _ = build_environment(sky_image(), 1.0,
                                                             ROTATIONS[request.param])
    return image, marginal, conditional, rot


# --- the sampler and its density ------------------------------------------------------------------


@alloc_kernel
def _uv_many(rot, d):
    out = np.empty((d.shape[0], 2))
    for i in range(d.shape[0]):
        u, v, _ = direction_to_uv(rot, (d[i, 0], d[i, 1], d[i, 2]))
        out[i, 0], out[i, 1] = u, v
    return out


def test_environment_sampling_chi2_uv(rng, chi2_points, env):
    # In the image's (u, v), with bins that split every cell of the distribution in whole (two
    # columns of bins a cell: its edges sit half a texel off the texel edges), so that the
    # claimed density's integral over each bin is exact despite the sun's one-texel spike.
    image, marginal, conditional, rot = env
    h, w = image.shape[:2]

    def sampler(n):
        wi = _sample_many(image, marginal, conditional, rot, rng.random((n, 2)))[0]
        return _uv_many(rot, wi)

    def pdf(x):
        th, ph = np.pi * x[:, 1], 2 * np.pi * x[:, 0]
        local = np.stack([np.sin(ph) * np.sin(th), np.cos(th), -np.cos(ph) * np.sin(th)], axis=1)
        p = _pdf_many(image, marginal, conditional, rot, local @ rot.T)
        return p * 2 * np.pi**2 * np.sin(th)

    chi2_points(sampler, pdf, N, shape=(2 * w, h - 1), sub=4, what="environment_sample (u, v)")


def test_environment_sampling_chi2_directions(rng, chi2_directions):
    # On the sphere, against the solid-angle density: a smooth sky (no spike for the quadrature
    # of the cells to miss), turned so that no cell of the test lines up with the image's.
    img = sky_image()
    img[3, 17] = img[3, 16]
    img[img.sum(axis=2) == 0.0] = 0.05
    image, marginal, conditional, rot, _ = build_environment(img, 1.0, ROTATIONS["tilted"])
    chi2_directions(lambda n: _sample_many(image, marginal, conditional, rot,
                                           rng.random((n, 2)))[0],
                    lambda w: _pdf_many(image, marginal, conditional, rot, w), N, n_cos=30,
                    n_phi=40, sub=16, what="environment_sample")


def test_sampled_pdf_and_radiance_agree_with_the_lookups(rng, env):
    image, marginal, conditional, rot = env
    wi, le, pdf = _sample_many(image, marginal, conditional, rot, rng.random((20_000, 2)))
    ok = pdf > 0.0
    assert ok.mean() > 0.999
    np.testing.assert_allclose(pdf[ok], _pdf_many(image, marginal, conditional, rot, wi[ok]),
                               rtol=1e-6)
    np.testing.assert_allclose(le[ok], _radiance_many(image, rot, wi[ok]), rtol=1e-5,
                               atol=1e-6)


def test_pdf_integrates_to_one(rng, env):
    image, marginal, conditional, rot = env
    # Monte Carlo over uniform directions: E[4π p(ω)] = ∫ p dω. 2·10⁶ samples of a density whose
    # largest value (the sun's cell) is ~40 times its mean: standard error < 0.5 %.
    d = uniform_directions(rng, 2_000_000)
    integral = 4.0 * np.pi * _pdf_many(image, marginal, conditional, rot, d).mean()
    assert integral == pytest.approx(1.0, abs=0.015)
    # And exactly, on a grid of (u, v) midpoints that every cell holds a whole number of
    h, w = 12, 24
    k = 8
    u = (np.arange(2 * k * w) + 0.5) / (2 * k * w)
    v = (np.arange(k * (h - 1)) + 0.5) / (k * (h - 1))
    uu, vv = np.meshgrid(u, v)
    th, ph = np.pi * vv.ravel(), 2 * np.pi * uu.ravel()
    local = np.stack([np.sin(ph) * np.sin(th), np.cos(th), -np.cos(ph) * np.sin(th)], axis=1)
    p = _pdf_many(image, marginal, conditional, rot, local @ rot.T)
    # dω = 2π² sin θ du dv
    assert np.sum(p * 2 * np.pi**2 * np.sin(th)) / uu.size == pytest.approx(1.0, rel=1e-9)


def test_light_sampling_estimate_is_unbiased(rng, env):
    # ∫ L dω by the light's own samples (L/p) against a fine quadrature of the bilinear lookup:
    # fails if the density is 0 anywhere the radiance is not (the black patch's edges, the seam).
    image, marginal, conditional, rot = env
    _, le, pdf = _sample_many(image, marginal, conditional, rot, rng.random((400_000, 2)))
    ok = pdf > 0.0
    estimate = (le[ok] / pdf[ok, None]).sum(axis=0) / len(pdf)
    d = uniform_directions(np.random.default_rng(11), 2_000_000)
    quadrature = 4.0 * np.pi * _radiance_many(image, rot, d).mean(axis=0)
    np.testing.assert_allclose(estimate, quadrature, rtol=0.02)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_cell_weights_are_the_bilinear_means(k):
    # A part of a cell is weighted wherever the bilinear radiance is > 0 in it, by its mean there
    # (checked against a fine quadrature of the lookup, with sin θ at the part's centre)
    img = np.zeros((5, 8, 3), np.float32)
    img[2, 7] = 1.0
    img[4, 0] = 0.5
    f = cell_weights(img, k)
    assert f.shape == (4 * k, 8 * k)
    m = 8 * k
    frac = (np.arange(m) + 0.5) / m
    for r, c in [(1 * k, 6 * k), (2 * k - 1, 8 * k - 1), (3 * k, 7 * k), (0, 0), (0, 3 * k)]:
        # Lookup coordinates inside the part (midpoints: exact for a bilinear function)
        x, y = np.meshgrid((c + frac) / k, (r + frac) / k)
        u, v = ((x + 0.5) / 8 % 1.0).ravel(), (y / 4).ravel()
        vals = np.array([environment_radiance(img, ui, vi)[0]
                         for ui, vi in zip(u, v, strict=True)])
        lum = vals.mean() * np.sin(np.pi * (r + 0.5) / (4 * k))  # R = G = B: luminance = R
        assert f[r, c] == pytest.approx(lum, rel=1e-9, abs=1e-12), (r, c)
    assert f[k, 6 * k] > 0 and f[2 * k - 1, 8 * k - 1] > 0 and f[0, 3 * k] == 0


# --- orientation ----------------------------------------------------------------------------------


def probe_image(h: int = 9, w: int = 16) -> np.ndarray:
    """Red = column, green = row, blue = 1: which texel a direction reads is plain."""
    img = np.ones((h, w, 3), np.float32)
    img[..., 0] = np.arange(w)[None, :]
    img[..., 1] = np.arange(h)[:, None]
    return img


def test_orientation_closed_form():
    # +X looks at u = 0.25 (red = 0.25·16 − 0.5 = 3.5), −Z at the seam (red: between the last
    # column and the first, 7.5), +Z at u = 0.5; +Y the top row, −Y the bottom one.
    img = probe_image()
    probes = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 0, 1.0], [-1.0, 0, 0], [0, 1.0, 0],
                       [0, -1.0, 0]])
    got = _radiance_many(img, np.eye(3), probes)
    np.testing.assert_allclose(got[:4, 0], [3.5, 7.5, 7.5, 11.5], atol=1e-12)
    np.testing.assert_allclose(got[:4, 1], 4.0, atol=1e-12)  # the horizon: the middle row
    np.testing.assert_allclose(got[4:, 1], [0.0, 8.0], atol=1e-12)
    # A rotation of 90° about +Y carries +X to −Z: −Z now reads what +X read
    rot = rotation_matrix((0, 1, 0), 90.0)
    np.testing.assert_allclose(_radiance_many(img, rot, probes[1:2]), got[0:1], atol=1e-9)


@pytest.mark.mitsuba
def test_lookup_agrees_with_mitsuba_envmap(rng):
    # Mitsuba 3's envmap with the same image and to_world = the rotation: the same radiance in
    # every direction (a mirrored or rotated image, or a half-texel shift, fails)
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    img = probe_image()
    img[..., 2] = np.random.default_rng(2).random(img.shape[:2])
    rot = rotation_matrix((0.3, 1.0, -0.2), 61.0)
    emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(img),
                            "to_world": mi.ScalarTransform4f(np.pad(rot, ((0, 1), (0, 1)))
                                                             + np.diag([0, 0, 0, 1.0]))})
    d = uniform_directions(rng, 300)
    d = d[np.abs(d @ rot[:, 1]) < 0.995]  # off the poles, where φ is undefined
    theirs = []
    for di in d:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-di))
        theirs.append(np.array(emitter.eval(si)))
    np.testing.assert_allclose(_radiance_many(img, rot, d), np.array(theirs), rtol=2e-4,
                               atol=2e-4)


# --- through the path tracer ----------------------------------------------------------------------


def write_pfm(path, image) -> str:
    path.write_bytes(encode_pfm(np.asarray(image, np.float32)))
    return str(path)


def env_scene(image_path, materials, objects, *, camera=None, film=(32, 32), spp=64, rotate=None,
              scale=1.0, max_depth=-1, seed=5):
    env = {"image": image_path, "scale": scale}
    if rotate is not None:
        env["rotate"] = rotate
    return load_scene({
        "camera": camera or {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 32},
        "film": {"width": film[0], "height": film[1]},
        "render": {"spp": spp, "seed": seed, "max_depth": max_depth},
        "environment": env,
        "materials": materials,
        "objects": objects,
    }, allow_paths=True)


def test_white_furnace_diffuse(tmp_path):
    # A white Lambertian sphere under a constant environment image of radiance 2 is 2 everywhere
    path = write_pfm(tmp_path / "grey.pfm", np.ones((6, 12, 3)))
    s = env_scene(path, {"w": {"type": "diffuse", "albedo": [1, 1, 1]}},
                  [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}],
                  scale=2.0)
    img = render(s)
    assert img.mean() == pytest.approx(2.0, rel=2e-3)


@pytest.mark.parametrize("direction,colour", [([1, 0, 0], 0), ([0, 0, -1], 1), ([0, 1, 0], 2)])
def test_render_orientation(tmp_path, direction, colour):
    # An image whose +X quarter is red, −Z seam green, top rows blue: a camera at the origin
    # looking along ``direction`` sees that colour (a mirrored image fails the +X case, a
    # flipped one the +Y case)
    h, w = 16, 32
    img = np.zeros((h, w, 3), np.float32)
    img[4:12, 6:10, 0] = 1.0  # u ≈ 0.25: +X
    img[4:12, :2, 1] = img[4:12, -2:, 1] = 1.0  # the seam: −Z
    img[:2, :, 2] = 1.0  # the top rows: +Y
    path = write_pfm(tmp_path / "probe.pfm", img)
    up = [0, 0, 1] if colour == 2 else [0, 1, 0]
    s = env_scene(path, {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
                  [{"type": "sphere", "center": [0, -50, 0], "radius": 0.1, "material": "w"}],
                  camera={"position": [0, 0, 0], "look_at": direction, "up": up, "fov": 5},
                  film=(4, 4), spp=4)
    seen = render(s).mean(axis=(0, 1))
    assert seen[colour] > 0.9 and np.delete(seen, colour).max() < 0.05, seen
    # Rotated by 90° about +Y, what +X showed is now at −Z
    if colour == 0:
        s = env_scene(path, {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
                      [{"type": "sphere", "center": [0, -50, 0], "radius": 0.1, "material": "w"}],
                      camera={"position": [0, 0, 0], "look_at": [0, 0, -1], "fov": 5},
                      film=(4, 4), spp=4, rotate={"axis": [0, 1, 0], "angle": 90})
        assert render(s).mean(axis=(0, 1))[0] > 0.9


def test_light_sample_and_bsdf_sample_agree(tmp_path):
    # A diffuse sphere under the sky, lit only by the BSDF's samples (max_depth large, but the
    # image through MIS) against the same with the sun moved: direct light must match what the
    # integral of the environment against the cosine lobe gives at the sphere's top point.
    img = sky_image()
    path = write_pfm(tmp_path / "sky.pfm", img)
    s = env_scene(path, {"w": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}},
                  [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}],
                  camera={"position": [0, 3, 0], "look_at": [0, 0, 0], "up": [0, 0, -1],
                          "fov": 2},
                  film=(2, 2), spp=4096, max_depth=1)
    seen = render(s).mean(axis=(0, 1))
    # At the top point (normal +Y, unoccluded above): L = ρ/π ∫ L_env cos θ dω over the upper
    # hemisphere, by quadrature of the bilinear lookup
    d = uniform_directions(np.random.default_rng(3), 2_000_000)
    up = d[:, 1] > 0.0
    le = _radiance_many(img, np.eye(3), d[up])
    expected = 0.8 / np.pi * 4 * np.pi * (le * d[up, 1:2]).sum(axis=0) / len(d)
    np.testing.assert_allclose(seen, expected, rtol=0.03)


TRANSLUCENT = {"type": "translucent", "ior": 1.4, "albedo": [0.9, 0.8, 0.6], "density": 4.0,
               "g": 0.2}
METHODS = {
    "volumetric": TRANSLUCENT | {"method": "volumetric"},
    "volumetric_index_matched": TRANSLUCENT | {"method": "volumetric", "ior": 1.0},
    "rough_volumetric": TRANSLUCENT | {"method": "volumetric", "roughness": 0.3},
    "single_scatter": TRANSLUCENT | {"method": "single_scatter"},
    "diffuse_entry": TRANSLUCENT | {"method": "diffuse_entry", "direct_light": True},
    "backlight": TRANSLUCENT | {"method": "backlight"},
    "diffusion": TRANSLUCENT | {"method": "diffusion"},
    "rough_glass": {"type": "dielectric", "ior": 1.5, "roughness": 0.3},
}


@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_sees_a_constant_environment_as_the_background(tmp_path, method):
    # A constant environment image is the constant background by another light: sampled by the
    # image's distribution instead of uniformly, through every method's next-event estimates
    # (the medium's for index-matched and single-scatter media, the surface's, diffuse_entry's
    # separate direct light, backlight's transmitted term). The two images' frame means agree
    # to 1.5 % (each ~1000 pixels × 256 spp: noise ~0.3 %; the object covers ~30 % of the frame).
    colour = [0.6, 0.7, 0.9]
    path = write_pfm(tmp_path / "flat.pfm", np.ones((8, 16, 3)) * np.array(colour))
    objects = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"},
               {"type": "quad", "origin": [-3, -1, 3], "edge1": [6, 0, 0], "edge2": [0, 0, -6],
                "material": "floor"}]
    materials = {"m": METHODS[method], "floor": {"type": "diffuse", "albedo": [0.5, 0.4, 0.3]}}
    camera = {"position": [0, 1, 4], "look_at": [0, -0.2, 0], "fov": 40}
    with_env = render(env_scene(path, materials, objects, camera=camera, spp=256))
    with_background = render(load_scene({
        "camera": camera, "film": {"width": 32, "height": 32},
        "render": {"spp": 256, "seed": 9}, "background": colour,
        "materials": materials, "objects": objects}))
    np.testing.assert_allclose(with_env.mean(axis=(0, 1)), with_background.mean(axis=(0, 1)),
                               rtol=0.015)
