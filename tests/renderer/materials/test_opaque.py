"""`auto`'s effectively opaque regime: the semi-infinite albedo, the rule, the surface rendered."""

from __future__ import annotations

import copy
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from renderer.materials import auto
from renderer.materials.diffusion import MS_ALBEDO, OPAQUE
from renderer.materials.opaque import opaque_albedo, semi_infinite_albedo
from renderer.render import render_buffer
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from tests.conftest import h_function

ROOT = Path(__file__).resolve().parents[3]
CSV = ROOT / "docs" / "images" / "accuracy" / "opaque.csv"


def test_h_function_solver_meets_its_closed_form():
    """The solver used as the reference: its zeroth moment is 2(1 − √(1−ϖ))/ϖ (Chandrasekhar's
    identity, which a wrong kernel or quadrature breaks)."""
    for albedo in (0.3, 0.9, 0.99):
        mu, w, h = h_function(albedo)
        assert (w * h).sum() == pytest.approx(2 * (1 - math.sqrt(1 - albedo)) / albedo, rel=1e-9)


@pytest.mark.parametrize("albedo", [0.3, 0.5, 0.9, 0.99])
def test_semi_infinite_albedo_matches_chandrasekhar(albedo):
    """Index-matched, isotropic, cosine-weighted incidence: the escape probability is the
    spherical albedo 1 − 2√(1−ϖ)·∫₀¹H(μ)μ dμ of a semi-infinite medium."""
    mu, w, h = h_function(albedo)
    exact = 1 - 2 * math.sqrt(1 - albedo) * (w * mu * h).sum()
    mean, se = semi_infinite_albedo(albedo, 0.0, 1.0, 200_000, 3)
    assert abs(mean - exact) < 4 * se, (mean, se, exact)


def test_albedo_near_one_follows_the_diffusion_limit():
    """Above LONG_WALKS the albedo is extrapolated, not walked (bounded cost); at ϖ = 0.99999,
    index-matched, it still meets Chandrasekhar's value within 0.1 %."""
    mu, w, h = h_function(0.99999)
    exact = 1 - 2 * math.sqrt(1 - 0.99999) * (w * mu * h).sum()
    assert opaque_albedo(0.99999, 0.0, 1.0) == pytest.approx(exact, abs=1e-3)


def test_boundary_and_absorption_limits():
    # Nothing absorbed: everything comes back (exactly, not by a walk that might be cut short)
    assert opaque_albedo(1.0, 0.5, 1.4) == 1.0
    assert opaque_albedo(0.0, 0.0, 1.4) == 0.0
    # A mismatched boundary reflects light back in, where more of it is absorbed
    matched = semi_infinite_albedo(0.9, 0.0, 1.0, 100_000, 1)[0]
    coated = semi_infinite_albedo(0.9, 0.0, 1.5, 100_000, 1)[0]
    assert coated < matched - 0.02
    # Forward scattering carries the light deeper: less of it comes back
    assert semi_infinite_albedo(0.9, 0.8, 1.0, 100_000, 1)[0] < matched - 0.05


def _dense_sphere(density: float, albedo: float = 0.95, width: int = 64, target=None) -> dict:
    scene = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    scene["film"] = {"width": width, "height": width * 3 // 4}
    scene["materials"]["wax"].update(method="auto", albedo=[albedo] * 3, density=density, g=0.0)
    scene["render"]["target_error"] = target
    return scene


def test_the_rule_depends_on_the_pixel_and_the_object():
    """The same dense wax is a surface in a 64-pixel image and translucent in a 2048-pixel one
    (the light's reach, 0.013 at density 2000, is a third of a pixel there, ten pixels here); and
    the rule needs its measured error to meet the target."""
    low = auto.auto_choice(load_scene(_dense_sphere(2000.0, target=1.0)), "wax")
    assert low.method == "opaque", low
    assert "effectively opaque" in low.reason
    assert low.expected_error == auto.opaque_error(0.95, 0.0) == 0.00326
    high = auto.auto_choice(load_scene(_dense_sphere(2000.0, width=2048, target=1.0)), "wax")
    assert high.method != "opaque", high
    if auto.opaque_error(0.95, 0.0) > 1e-6:
        strict = auto.auto_choice(load_scene(_dense_sphere(2000.0, target=1e-6)), "wax")
        assert strict.method != "opaque", strict


def test_opaque_error_is_the_measured_one():
    """auto's OPAQUE_ERROR is the largest opaque relMSE of the committed measurement (rounded up
    to 3 significant digits), and auto picked the opaque surface in every measured case."""
    rows = list(csv.DictReader(CSV.open()))
    assert len(rows) >= 16 and {r["auto_method"] for r in rows} == {"opaque"}
    worst = max(float(r["opaque_rel_mse"]) for r in rows)
    assert worst <= auto.OPAQUE_ERROR < worst * 1.01 + 1e-12


def test_opaque_error_by_albedo_is_the_measured_one_at_each_albedo():
    """auto's OPAQUE_ERROR_BY_ALBEDO is, at each albedo of the committed measurement, its largest
    opaque relMSE over the g and densities measured (rounded up to 3 significant digits); it
    grows with the albedo (what lets an albedo between two take the next one up's), and the g
    measured reach OPAQUE_MEASURED_G."""
    rows = list(csv.DictReader(CSV.open()))
    albedos = sorted({float(r["albedo"]) for r in rows})
    assert [a for a, _ in auto.OPAQUE_ERROR_BY_ALBEDO] == albedos
    for a, error in auto.OPAQUE_ERROR_BY_ALBEDO:
        worst = max(float(r["opaque_rel_mse"]) for r in rows if float(r["albedo"]) == a)
        assert worst <= error < worst * 1.01 + 1e-12, a
    errors = [e for _, e in auto.OPAQUE_ERROR_BY_ALBEDO]
    assert errors == sorted(errors) and errors[-1] == auto.OPAQUE_ERROR
    assert max(float(r["g"]) for r in rows) == auto.OPAQUE_MEASURED_G


@pytest.mark.parametrize(("albedo", "g", "want"), [
    (0.1, 0.0, 0.000788), (0.3, 0.5, 0.000788), (0.5, 0.2, 0.00189), ([0.2, 0.9, 0.5], 0.0,
                                                                      0.00326),
    (0.96, 0.0, 0.00847), (0.995, 0.0, 0.00847), (0.5, 0.6, 0.00847), (0.5, -0.7, 0.00847)])
def test_opaque_error_takes_the_next_albedo_measured_up_and_the_largest_beyond(albedo, g, want):
    assert auto.opaque_error(albedo, g) == want


def test_a_strict_target_takes_the_opaque_surface_where_its_albedos_error_meets_it():
    """At target 0.005, under the largest measured error (0.00847, albedo 0.99) but above albedo
    0.8's (0.00189): dense wax of albedo 0.8 is the opaque surface, with that error as its
    expected bias; of albedo 0.99, or of 0.8 with g 0.8 (beyond the g measured), it is not."""
    low = auto.auto_choice(load_scene(_dense_sphere(2000.0, albedo=0.8, target=0.005)), "wax")
    assert low.method == "opaque" and low.expected_error == 0.00189, low
    assert "measured error 0.00189 <= target 0.005" in low.reason
    high = auto.auto_choice(load_scene(_dense_sphere(2000.0, albedo=0.99, target=0.005)), "wax")
    assert high.method == "volumetric", high
    forward = _dense_sphere(2000.0, albedo=0.8, target=0.005)
    forward["materials"]["wax"]["g"] = 0.8
    assert auto.auto_choice(load_scene(forward), "wax").method == "volumetric"
    # the same per channel: blue at albedo 0.8 is opaque at 0.005, red at 0.99 is not
    mixed = _dense_sphere(2000.0, albedo=0.8, target=0.005)
    mixed["materials"]["wax"].update(albedo=[0.99, 0.8, 0.8], density=[2000.0, 2000.0, 2100.0])
    assert auto.channel_regimes(
        [0.99, 0.8, 0.8], [2000.0, 2000.0, 2100.0], 0.5, 0.005, ior=1.4,
        footprint=auto.pixel_footprint(load_scene(mixed), load_scene(mixed).objects[5:6]),
    ) == ("translucent", "opaque", "opaque")


def test_compiled_as_the_zero_radius_limit():
    scene = load_scene(_dense_sphere(2000.0, target=1.0))
    cs = compile_scene(scene)
    assert cs.info["auto"]["wax"]["method"] == "opaque"
    row = cs.arrays.mat_param[list(scene.materials).index("wax")]
    assert row[OPAQUE] == 1.0
    np.testing.assert_allclose(row[MS_ALBEDO:MS_ALBEDO + 3], opaque_albedo(0.95, 0.0, 1.4))


def _furnace(albedo: float, ior: float, density: float = 1e4, spp: int = 64):
    return render_buffer(load_scene({
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": 16, "height": 16},
        "render": {"spp": spp, "max_depth": -1, "seed": 2},
        "background": [1, 1, 1],
        "materials": {"m": {"type": "translucent", "method": "auto", "ior": ior,
                            "albedo": [albedo] * 3, "density": density, "g": 0.0}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}],
    }))


@pytest.fixture
def opaque_always(monkeypatch):
    """The opaque regime whatever error auto assumes for it (the rule's own tests are above;
    opaque_error is at most OPAQUE_ERROR)."""
    monkeypatch.setattr(auto, "OPAQUE_ERROR", 0.0)


@pytest.mark.parametrize("ior", [1.0, 1.4, 2.5])
def test_white_furnace(opaque_always, ior):
    """Albedo 1 under a uniform background: the coat reflects F, the rest all comes back out
    (A = 1) through a lobe that integrates to one: the sphere vanishes (central 8×8 pixels = 1
    within 6 standard errors, plus the 0.5 % of the Fresnel-moment fit in c)."""
    buf = _furnace(1.0, ior)
    pixel = buf.sum[4:12, 4:12, 0] / buf.count[4:12, 4:12]
    se = math.sqrt(buf.variance_of_mean()[4:12, 4:12, 0].sum()) / 64
    assert abs(pixel.mean() - 1.0) < 6 * se + 0.005, (pixel.mean(), se)


@pytest.mark.parametrize(("albedo", "ior", "density"),
                         [(0.0, 1.4, 1e4), (0.5, 1.0, 1e6), (0.999, 2.5, 1e9), (0.99, 1.001, 1e3)])
def test_stability(opaque_always, albedo, ior, density):
    """Extreme densities, albedo 0 and near 1, index 1 and 2.5: finite, non-negative, and no
    energy above the furnace bound."""
    buf = _furnace(albedo, ior, density, spp=16)
    assert buf.total_dropped == 0
    pixel = buf.sum / np.maximum(buf.count, 1)[..., None]
    assert np.all(np.isfinite(pixel)) and np.all(pixel >= 0)
    assert pixel[4:12, 4:12].mean() <= 1.0 + 0.005


def test_against_mitsuba(opaque_always):
    """A dense grey sphere (albedo 0.95, σt 800, ior 1.4) in the Cornell box, against Mitsuba 3's
    volpath random walk at 16384 spp (tests/data/dense_sphere_ref.npy): the object's mean within
    3 % and its relMSE within auto's OPAQUE_ERROR plus this render's own noise."""
    from bench.accuracy import object_mask, rel_mse

    scene = _dense_sphere(800.0)
    scene["render"].update(spp=256, seed=7, target_error=None)
    ref = np.load(ROOT / "tests" / "data" / "dense_sphere_ref.npy").astype(np.float64)
    img = render_buffer(load_scene(copy.deepcopy(scene))).mean()
    mask = object_mask(scene, "wax")
    assert img[mask].mean() / ref[mask].mean() == pytest.approx(1.0, abs=0.03)
    assert rel_mse(img, ref, mask) < 2 * max(auto.OPAQUE_ERROR, 0.01)
