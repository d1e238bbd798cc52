"""Chromatic media (scene format v1.1, "Chromatic and measured media"): σt per channel.

The volumetric walk samples a flight from one channel and weights every channel by the balance
heuristic over the three (renderer/integrators/subsurface/volumetric.py). Checked here:
- the sampler: the flights' distribution (chi²) and the weights' expectations (moments), which are
  each channel's own transmittance and scattering density whichever channel was sampled;
- closed forms: a semi-infinite slab whose channels have different albedos and σt 100× apart
  gives each channel Chandrasekhar's plane albedo of its own albedo (a semi-infinite medium's
  reflectance does not depend on σt), all from one render; a white furnace with σt 1:10:100
  stays at 1 in every channel;
- the failure regimes: one channel 10⁴× denser than another, albedo 1 in one channel and 0 in
  another, presets at extreme scales: no NaN, no energy gain, no hang — in every method.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from renderer.integrators.subsurface.volumetric import (
    channel_probabilities,
    chromatic_flight,
    event_weights,
    pass_weights,
)
from renderer.render import render_buffer
from renderer.scene import load_scene
from tests.conftest import plane_albedo_normal

SIGMA = (1.0, 10.0, 100.0)
ALBEDO = (0.9, 0.5, 0.99)


@njit(cache=False)
def _flights(sigma, probs, us):
    out = np.empty(us.shape[0])
    for i in range(us.shape[0]):
        out[i] = chromatic_flight(sigma[0], sigma[1], sigma[2], probs[0], probs[1], probs[2],
                                  us[i])
    return out


@pytest.mark.parametrize("probs", [(1 / 3, 1 / 3, 1 / 3), (0.7, 0.2, 0.1), (0.0, 0.5, 0.5)])
def test_chromatic_flights_follow_the_channel_mixture(rng, chi2_counts, probs):
    """Flights are distributed as Σ_c P_c σt_c e^{−σt_c s}: chi² over bins equiprobable under
    the densest channel and a tail bin."""
    n = 200_000
    s = _flights(np.array(SIGMA), np.array(probs), rng.random(n))
    assert np.all(np.isfinite(s)) and np.all(s >= 0.0)
    edges = np.concatenate([[0.0], np.geomspace(1e-3, 5.0, 30), [np.inf]])
    cdf = sum(p * (1.0 - np.exp(-sig * edges)) for p, sig in zip(probs, SIGMA, strict=True))
    chi2_counts(np.histogram(s, edges)[0], n * np.diff(cdf), "chromatic_flight")


@pytest.mark.parametrize("probs", [(1 / 3, 1 / 3, 1 / 3), (0.7, 0.2, 0.1), (0.05, 0.05, 0.9)])
@pytest.mark.parametrize("t", [0.01, 0.2, 3.0])
def test_chromatic_weights_give_each_channel_its_own_medium(rng, probs, t):
    """Whichever channel a flight was sampled from, the weights make every channel's expectation
    its own: E[pass weight_k·1{s ≥ t}] = e^{−σt_k t} (the flight reaches the surface t away) and
    E[event weight_k·1{s < t}] = albedo_k (1 − e^{−σt_k t}) (it scatters first, weighted by σs)."""
    n = 200_000
    s = _flights(np.array(SIGMA), np.array(probs), rng.random(n))
    # the pass weight is the same for every flight that passed
    passed = np.where((s >= t)[:, None], np.array(pass_weights(*SIGMA, *probs, t)), 0.0)
    scattered = np.zeros((n, 3))
    for i in np.flatnonzero(s < t):
        scattered[i] = event_weights(*SIGMA, *ALBEDO, *probs, s[i])
    for k in range(3):
        exact_pass = math.exp(-SIGMA[k] * t)
        exact_event = ALBEDO[k] * (1.0 - math.exp(-SIGMA[k] * t))
        for values, exact in ((passed[:, k], exact_pass), (scattered[:, k], exact_event)):
            se = values.std() / math.sqrt(n)
            assert abs(values.mean() - exact) < 5 * se + 1e-12, (k, values.mean(), exact, se)


def test_channel_probabilities_follow_throughput_times_mean_free_path():
    # equal σt: the throughput alone
    assert channel_probabilities(2.0, 1.0, 1.0, 5.0, 5.0, 5.0) == pytest.approx((0.5, 0.25, 0.25))
    # equal throughput: the mean free path, 1/3 : 1/8 : 1/16 (the chromatic wax)
    w = np.array([1 / 3, 1 / 8, 1 / 16])
    assert channel_probabilities(1.0, 1.0, 1.0, 3.0, 8.0, 16.0) == pytest.approx(w / w.sum())
    assert channel_probabilities(2.0, 1.0, 1.0, 4.0, 1.0, 2.0) == pytest.approx((0.25, 0.5, 0.25))
    assert channel_probabilities(0.0, 0.0, 3.0, 1.0, 2.0, 3.0) == (0.0, 0.0, 1.0)
    for bad in ((0.0, 0.0, 0.0), (math.inf, 1.0, 1.0), (math.nan, 1.0, 1.0)):
        assert channel_probabilities(*bad, 1.0, 10.0, 100.0) == pytest.approx((1 / 3,) * 3)


def test_a_sampled_channel_with_no_share_is_never_used():
    """u at the very top of [0, 1) with P_b = 0 stays in the last channel that has a share."""
    u = 1.0 - 2.0**-53
    s = chromatic_flight(*SIGMA, 0.5, 0.5, 0.0, u)
    assert math.isfinite(s) and s > 0.0


def _medium(albedo, density, method="volumetric", **knobs):
    return {"type": "translucent", "method": method, "ior": 1.0, "albedo": list(albedo),
            "density": list(density), "g": 0.0} | knobs


def test_chromatic_semi_infinite_slab_gives_each_channel_its_own_albedo():
    """Index-matched, isotropic, semi-infinite (τ ≥ 100 in every channel), light along the normal:
    each channel's reflectance is Chandrasekhar's plane albedo 1 − H(1)√(1−ϖ) of its own albedo,
    whatever its σt (σt 1:3:10 here, so a grey walk at any one σt would not be semi-infinite and
    exact in the others at once). All three from one render, within 3 standard errors."""
    thickness = 10.0
    density = (10.0, 30.0, 100.0)
    scene = load_scene({
        "camera": {"position": [0, 0, thickness / 2 + 5], "look_at": [0, 0, 0], "fov": 1},
        "film": {"width": 8, "height": 8},
        "render": {"spp": 512, "max_depth": -1, "seed": 3},
        "background": [1, 1, 1],
        "materials": {"medium": _medium(ALBEDO, density),
                      "black": {"type": "diffuse", "albedo": [0, 0, 0]}},
        "objects": [{"type": "box", "min": [-50, -50, -thickness / 2],
                     "max": [50, 50, thickness / 2], "material": "medium"},
                    {"type": "quad", "origin": [-1000, -1000, -thickness / 2 - 0.01],
                     "edge1": [2000, 0, 0], "edge2": [0, 2000, 0], "material": "black"}],
    })
    buf = render_buffer(scene)
    for k in range(3):
        mean = buf.sum[..., k].sum() / buf.count.sum()
        se = math.sqrt(buf.variance_of_mean()[..., k].sum()) / buf.count.size
        exact = plane_albedo_normal(ALBEDO[k])
        assert abs(mean - exact) < 3 * se, (k, mean, exact, se)


def _slab(density, spp=1024):
    """van de Hulst's slab (thickness 1, albedo 0.9, g 0.75, index-matched, black below): the
    reflectance for light along the normal, per channel, with its standard error."""
    scene = load_scene({
        "camera": {"position": [0, 0, 5.5], "look_at": [0, 0, 0], "fov": 1},
        "film": {"width": 8, "height": 8},
        "render": {"spp": spp, "max_depth": -1, "seed": 1},
        "background": [1, 1, 1],
        "materials": {"medium": {"type": "translucent", "method": "volumetric", "ior": 1.0,
                                 "albedo": [0.9] * 3, "density": density, "g": 0.75},
                      "black": {"type": "diffuse", "albedo": [0, 0, 0]}},
        "objects": [{"type": "box", "min": [-50, -50, -0.5], "max": [50, 50, 0.5],
                     "material": "medium"},
                    {"type": "quad", "origin": [-1000, -1000, -0.51], "edge1": [2000, 0, 0],
                     "edge2": [0, 2000, 0], "material": "black"}],
    })
    buf = render_buffer(scene)
    mean = buf.sum.sum(axis=(0, 1)) / buf.count.sum()
    se = np.sqrt(buf.variance_of_mean().sum(axis=(0, 1))) / buf.count.size
    return mean, se


def test_chromatic_slab_gives_each_channel_its_grey_slab():
    """A finite slab, where σt matters (optical thickness 2, 0.5, 8 by channel): the red channel
    meets van de Hulst's 0.09739 (τ 2, albedo 0.9, g 0.75), and every channel agrees with a grey
    render at that channel's σt, within 3 standard errors of the difference. A walk that used one
    σt for all channels fails both."""
    mean, se = _slab([2.0, 0.5, 8.0])
    assert abs(mean[0] - 0.09739) < 3 * se[0], (mean[0], se[0])
    for k, density in ((1, 0.5), (2, 8.0)):
        grey, grey_se = _slab(density)
        tol = 3 * math.hypot(se[k], grey_se[k])
        assert abs(mean[k] - grey[k]) < tol, (k, mean[k], grey[k], tol)


def _furnace(material, spp=64, seed=2):
    scene = load_scene({
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
        "film": {"width": 16, "height": 16},
        "render": {"spp": spp, "max_depth": -1, "seed": seed},
        "background": [1, 1, 1],
        "materials": {"m": material},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}],
    })
    return render_buffer(scene)


@pytest.mark.parametrize("ior", [1.0, 1.5])
def test_chromatic_white_furnace_stays_at_one_in_every_channel(ior):
    """Albedo 1, σt 1:10:100 (per unit radius 0.5, 5, 50): nothing is absorbed in any channel, so
    every channel of the object's pixels is 1 within 6 standard errors."""
    buf = _furnace(_medium((1, 1, 1), (0.5, 5.0, 50.0)) | {"ior": ior}, spp=128)
    for k in range(3):
        var = buf.variance_of_mean()[4:12, 4:12, k]
        mean = (buf.sum[4:12, 4:12, k] / buf.count[4:12, 4:12]).mean()
        se = math.sqrt(var.sum()) / var.size
        assert abs(mean - 1.0) < 6 * se + 1e-9, (k, mean, se)


STABILITY = {
    "one channel 1e4 denser": dict(albedo=(0.9, 0.9, 0.9), density=(0.1, 1.0, 1000.0)),
    "albedo 1 and 0": dict(albedo=(1.0, 0.0, 0.5), density=(1.0, 4.0, 16.0)),
    "preset at 1e-4": dict(preset="skin1", preset_scale=1e-4),
    "preset at 1e4": dict(preset="ketchup", preset_scale=1e4),
}


@pytest.mark.parametrize("method", ["volumetric", "single_scatter", "diffuse_entry", "backlight",
                                    "diffusion", "auto"])
@pytest.mark.parametrize("case", list(STABILITY))
def test_chromatic_failure_regimes_stay_finite_and_bounded(case, method):
    """Every method in the chromatic failure regimes, under a uniform background of radiance 1:
    no dropped (non-finite) sample, no negative value, and no channel of the object's pixels
    brighter than the background on average (a closed object cannot return more than arrives)
    beyond 6 standard errors, in bounded time."""
    knobs = dict(STABILITY[case])
    material = {"type": "translucent", "method": method, "ior": 1.3, "g": 0.3}
    if "preset" in knobs:
        material |= knobs
    else:
        material |= {"albedo": list(knobs["albedo"]), "density": list(knobs["density"])}
    buf = _furnace(material, spp=32)
    assert buf.dropped.sum() == 0
    img = buf.sum / buf.count[..., None]
    assert np.all(np.isfinite(img)) and np.all(img >= 0.0)
    for k in range(3):
        var = buf.variance_of_mean()[4:12, 4:12, k]
        se = math.sqrt(var.sum()) / var.size
        assert img[4:12, 4:12, k].mean() < 1.0 + 6 * se + 1e-9, (k, img[4:12, 4:12, k].mean(), se)
