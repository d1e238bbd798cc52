"""The smooth conductor: its Fresnel term against closed forms, the scene form, its stability."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.materials.conductor import CONDUCTOR_PRESETS, fresnel_conductor
from renderer.materials.fresnel import fresnel_dielectric
from renderer.render import render_buffer
from renderer.scene import SceneError, load_scene


@pytest.mark.parametrize("eta, k", [(0.18299, 3.4242), (1.3456, 7.4746), (2.5, 0.0), (0.2, 0.5)])
def test_normal_incidence_is_the_closed_form(eta, k):
    """R(0°) = ((η − 1)² + k²) / ((η + 1)² + k²) (Born & Wolf, §14.2)."""
    exact = ((eta - 1) ** 2 + k * k) / ((eta + 1) ** 2 + k * k)
    assert fresnel_conductor(1.0, eta, k) == pytest.approx(exact, rel=1e-12)


@pytest.mark.parametrize("eta", [1.2, 1.5, 2.4])
def test_without_absorption_it_is_the_dielectric_fresnel(eta):
    for cos_i in np.linspace(0.0, 1.0, 41):
        assert fresnel_conductor(cos_i, eta, 0.0) == pytest.approx(
            fresnel_dielectric(cos_i, eta)[0], abs=1e-12)


def test_grazing_incidence_reflects_everything_and_presets_are_metals():
    for (etas, ks) in CONDUCTOR_PRESETS.values():
        for eta, k in zip(etas, ks, strict=True):
            assert fresnel_conductor(0.0, eta, k) == pytest.approx(1.0)
            f = [fresnel_conductor(c, eta, k) for c in np.linspace(0, 1, 21)]
            assert all(0.0 < x <= 1.0 for x in f)
    # gold reflects red far more than blue; silver and aluminium are nearly white at 0°
    au = [fresnel_conductor(1.0, e, k) for e, k in zip(*CONDUCTOR_PRESETS["Au"], strict=True)]
    assert au[0] > 0.9 and au[2] < 0.5
    for name in ("Ag", "Al"):
        r = [fresnel_conductor(1.0, e, k) for e, k in zip(*CONDUCTOR_PRESETS[name], strict=True)]
        assert min(r) > 0.85


def _scene(material: dict) -> dict:
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": 16, "height": 16},
        "render": {"spp": 16, "max_depth": -1, "seed": 1},
        "background": [1, 1, 1],
        "materials": {"metal": material},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "metal"}],
    }


def test_a_conductor_under_a_white_background_returns_its_fresnel_mean():
    """A convex metal sphere under a uniform background of 1: each pixel sees one reflection, so
    it is F(θ) per channel exactly, below 1 and never NaN."""
    buf = render_buffer(load_scene(_scene({"type": "conductor", "preset": "Cu"})))
    img = buf.sum / buf.count[..., None]
    assert buf.dropped.sum() == 0 and np.all(np.isfinite(img))
    assert np.all(img <= 1.0 + 1e-12) and img[8, 8, 0] > img[8, 8, 2]
    center = [fresnel_conductor(1.0, e, k) for e, k in zip(*CONDUCTOR_PRESETS["Cu"], strict=True)]
    np.testing.assert_allclose(img[7:9, 7:9].mean(axis=(0, 1)), center, rtol=0.02)


@pytest.mark.parametrize(("material", "path", "message"), [
    ({"type": "conductor"}, "materials.metal",
     "a conductor needs eta and k, or a preset (Au, Ag, Cu, Al)"),
    ({"type": "conductor", "eta": [1, 1, 1]}, "materials.metal",
     "a conductor needs eta and k, or a preset (Au, Ag, Cu, Al)"),
    ({"type": "conductor", "preset": "Au", "k": [1, 1, 1]}, "materials.metal",
     "preset replaces eta and k; give one form (also given: k)"),
    ({"type": "conductor", "preset": "Au", "roughness": 1.5}, "materials.metal.roughness",
     "must be <= 1"),
    ({"type": "conductor", "eta": [1, 0, 1], "k": [1, 1, 1]}, "materials.metal.eta[1]",
     "must be > 0"),
])
def test_bad_conductors_are_named(material, path, message):
    with pytest.raises(SceneError) as err:
        load_scene(_scene(material))
    assert (path, message) in err.value.errors, err.value.errors


def test_the_preset_names_are_an_enum():
    with pytest.raises(SceneError) as err:
        load_scene(_scene({"type": "conductor", "preset": "Pt"}))
    assert any(p == "materials.metal.preset" for p, _ in err.value.errors)
    assert math.isfinite(fresnel_conductor(0.5, 0.2, 3.0))


# --- the rough metal (GGX) ------------------------------------------------------------------------

from renderer.materials.conductor import (  # noqa: E402
    rough_conductor_eval,
    rough_conductor_pdf,
    rough_conductor_sample,
)
from renderer.scene.compile import _material_row  # noqa: E402
from tests.conftest import at_angle, chi2_directions  # noqa: E402


def _rough_row(alpha: float) -> np.ndarray:
    from types import SimpleNamespace

    _, row = _material_row("m", SimpleNamespace(type="conductor", preset="Au", eta=None, k=None,
                                                specular=(1.0, 1.0, 1.0), roughness=alpha))
    return row


N = (0.0, 0.0, 1.0)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
@pytest.mark.parametrize("theta", [0.0, 45.0, 80.0])
def test_visible_normal_sampling_follows_its_pdf(rng, alpha, theta):
    """Chi² of the directions rough_conductor_sample draws against rough_conductor_pdf, which
    the BSDF's MIS weights use: G1(wo) D(h) / (4 cos θo) (Heitz 2018)."""
    row, wo = _rough_row(alpha), at_angle(theta)

    def sampler(n):
        u = rng.random((n, 2))
        out = np.full((n, 3), np.nan)
        for i in range(n):
            wi, _, _, ok = rough_conductor_sample(row, wo, N, u[i, 0], u[i, 1])
            if ok:
                out[i] = wi
        return out

    def pdf(w):
        return np.array([rough_conductor_pdf(row, wo, tuple(x), N) for x in w])

    # Cells even in θ over the upper hemisphere (a narrow lobe at the pole needs them small
    # there), and a finer quadrature of the pdf over each cell for a narrow lobe
    cos_edges = np.cos(np.linspace(np.pi / 2, 0.0, 46))
    chi2_directions(sampler, pdf, 40_000, cos_edges=cos_edges, n_phi=24,
                    sub=6 if alpha > 0.1 else 24, what=f"GGX alpha {alpha} theta {theta}")


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
def test_a_sample_weighs_eval_over_pdf(rng, alpha):
    """The sampled weight is f·cos/pdf per channel (F·G1(wi) in closed form)."""
    row, wo = _rough_row(alpha), at_angle(30.0)
    for u1, u2 in rng.random((200, 2)):
        wi, w, pdf, ok = rough_conductor_sample(row, wo, N, u1, u2)
        if not ok:
            continue
        f = rough_conductor_eval(row, wo, wi, N)
        np.testing.assert_allclose(w, np.array(f) / pdf, rtol=1e-9)
        assert pdf == pytest.approx(rough_conductor_pdf(row, wo, wi, N), rel=1e-12)


def test_the_rough_metal_reflects_no_more_than_the_smooth_one(rng):
    """∫ f cos dωi (the mean sampled weight) is at most F at normal incidence's scale: masking
    only loses light (with F ≤ 1 per channel), and tends to the smooth metal's F as α → 0."""
    wo = at_angle(20.0)
    smooth = [fresnel_conductor(math.cos(math.radians(20.0)), e, k)
              for e, k in zip(*CONDUCTOR_PRESETS["Au"], strict=True)]
    for alpha in (1e-4, 0.2, 0.6, 1.0):
        row = _rough_row(alpha)
        total = np.zeros(3)
        for u1, u2 in rng.random((4000, 2)):
            _, w, _, ok = rough_conductor_sample(row, wo, N, u1, u2)
            if ok:
                total += w
        mean = total / 4000
        assert np.all(mean <= 1.0) and np.all(np.isfinite(mean))
        if alpha == 1e-4:
            np.testing.assert_allclose(mean, smooth, rtol=1e-3)
