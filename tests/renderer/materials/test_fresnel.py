"""Fresnel reflectance, Snell refraction and the smooth dielectric sampler against closed forms.

The references are written independently of renderer/materials/fresnel.py, which uses the cosine
form of the Fresnel equations with η = η_t/η_i: here Fresnel's sine/tangent form (Hecht, Optics,
5th ed., eqs. 4.42–4.43 rewritten with Snell's law, §4.6.2), the normal-incidence and Brewster
closed forms, and energy conservation through the *transmission* amplitudes (Hecht eqs. 4.44,
4.45 and 4.60–4.61: T = (n_t cos θt)/(n_i cos θi)·t²), which the implementation never computes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.materials.dielectric import dielectric_sample
from renderer.materials.fresnel import fresnel_dielectric, fresnel_dielectric_sp, reflect, refract

IORS = [1.33, 1.5, 2.4]  # water, crown glass, diamond
N_WORLD = tuple(np.array([0.2, 0.4, -0.9]) / np.linalg.norm([0.2, 0.4, -0.9]))


def direction_at(n, theta):
    """A unit vector at angle θ from the unit vector n (on n's side for θ < 90°)."""
    n = np.asarray(n)
    t = np.cross(n, [0.6, -0.3, 0.2])
    t /= np.linalg.norm(t)
    return tuple(math.sin(theta) * t + math.cos(theta) * n)


def snell_cos_t(theta_i, n1, n2):
    s = n1 / n2 * math.sin(theta_i)
    return math.sqrt(1.0 - s * s)


# --- closed forms ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n", IORS)
def test_normal_incidence(n):
    # Rs = Rp = ((n − 1)/(n + 1))² at θ = 0, from either side of the interface.
    expected = ((n - 1.0) / (n + 1.0)) ** 2
    for eta in (n, 1.0 / n):
        rs, rp, cos_t = fresnel_dielectric_sp(1.0, eta)
        assert rs == pytest.approx(expected, rel=1e-13)
        assert rp == pytest.approx(expected, rel=1e-13)
        assert cos_t == 1.0
        assert fresnel_dielectric(1.0, eta)[0] == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize("n", IORS)
def test_brewster_angle(n):
    # At θB = atan(n2/n1), θi + θt = 90°: Rp vanishes, and Hecht's rs = −sin(θi − θt)/sin(θi + θt)
    # becomes cos 2θB = (1 − n²)/(1 + n²) for relative index n. From inside the relative index is
    # 1/n and the same formulas hold.
    for rel in (n, 1.0 / n):
        theta_b = math.atan(rel)
        rs, rp, cos_t = fresnel_dielectric_sp(math.cos(theta_b), rel)
        assert rp < 1e-28  # zero to rounding (the amplitude is ~1e-16)
        assert rs == pytest.approx(((rel * rel - 1.0) / (rel * rel + 1.0)) ** 2, rel=1e-12)
        assert cos_t == pytest.approx(math.sin(theta_b), rel=1e-12)  # θt = 90° − θB
        # and Rp really has a minimum there, not a zero crossing of something else
        assert fresnel_dielectric_sp(math.cos(theta_b + 0.01), rel)[1] > 1e-7
        assert fresnel_dielectric_sp(math.cos(theta_b - 0.01), rel)[1] > 1e-7


@pytest.mark.parametrize("n", IORS)
def test_total_internal_reflection(n):
    # From inside (η = 1/n) everything beyond the critical angle asin(1/n) is reflected.
    theta_c = math.asin(1.0 / n)
    for theta in (theta_c + 1e-9, theta_c + 1e-3, 0.5 * (theta_c + math.pi / 2), math.pi / 2):
        f, cos_t = fresnel_dielectric(math.cos(theta), 1.0 / n)
        assert f == 1.0 and cos_t == 0.0
    f_below, cos_t_below = fresnel_dielectric(math.cos(theta_c - 1e-3), 1.0 / n)
    assert f_below < 1.0 and cos_t_below > 0.0
    # F rises continuously to 1 at the critical angle (1 − F ~ √Δθ there)
    assert 0.9 < fresnel_dielectric(math.cos(theta_c - 1e-8), 1.0 / n)[0] < 1.0
    # From outside there is no critical angle: F < 1 up to grazing, where F → 1.
    assert fresnel_dielectric(math.cos(math.radians(89.0)), n)[0] < 1.0
    assert fresnel_dielectric(0.0, n)[0] == pytest.approx(1.0, abs=1e-15)


def test_glass_at_45_degrees():
    # Crown glass, n = 1.5, 45° external incidence. Hecht's tables of the Fresnel equations give
    # Rs ≈ 0.0920 and Rp ≈ 0.00847 (and R = 0.0502 unpolarized); Fresnel's sine/tangent form gives
    # them to full precision: θt = asin(sin 45°/1.5) = 28.1255°, Rs = sin²(θi−θt)/sin²(θi+θt),
    # Rp = tan²(θi−θt)/tan²(θi+θt).
    ti = math.radians(45.0)
    tt = math.asin(math.sin(ti) / 1.5)
    rs_ref = (math.sin(ti - tt) / math.sin(ti + tt)) ** 2
    rp_ref = (math.tan(ti - tt) / math.tan(ti + tt)) ** 2
    rs, rp, cos_t = fresnel_dielectric_sp(math.cos(ti), 1.5)
    assert rs == pytest.approx(0.0920, abs=5e-5)
    assert rp == pytest.approx(0.00847, abs=5e-6)
    assert rs == pytest.approx(rs_ref, rel=1e-12)
    assert rp == pytest.approx(rp_ref, rel=1e-12)
    assert cos_t == pytest.approx(math.cos(tt), rel=1e-14)
    assert fresnel_dielectric(math.cos(ti), 1.5)[0] == pytest.approx(0.0502, abs=5e-5)


@pytest.mark.parametrize("n", IORS)
def test_sine_tangent_form_at_all_angles(n):
    # The implementation's cosine form against Fresnel's sine/tangent form, from both sides.
    for n1, n2 in ((1.0, n), (n, 1.0)):
        limit = math.asin(n2 / n1) if n1 > n2 else math.pi / 2
        for theta in np.linspace(0.01, limit - 1e-3, 40):
            tt = math.asin(n1 / n2 * math.sin(theta))
            rs_ref = (math.sin(theta - tt) / math.sin(theta + tt)) ** 2
            rp_ref = (math.tan(theta - tt) / math.tan(theta + tt)) ** 2
            rs, rp, _ = fresnel_dielectric_sp(math.cos(theta), n2 / n1)
            assert rs == pytest.approx(rs_ref, rel=1e-9, abs=1e-15)
            assert rp == pytest.approx(rp_ref, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("n", IORS)
def test_energy_conservation(n):
    # R + T = 1 for each polarization, T from the transmission amplitudes (Hecht 4.44–4.45):
    # ts = 2 n1 cos θi/(n1 cos θi + n2 cos θt), tp = 2 n1 cos θi/(n1 cos θt + n2 cos θi),
    # T = (n2 cos θt)/(n1 cos θi)·t².
    for n1, n2 in ((1.0, n), (n, 1.0)):
        limit = math.asin(n2 / n1) if n1 > n2 else math.pi / 2
        for theta in np.linspace(0.0, limit - 1e-4, 50):
            ci = math.cos(theta)
            ct = snell_cos_t(theta, n1, n2)
            ts = 2 * n1 * ci / (n1 * ci + n2 * ct)
            tp = 2 * n1 * ci / (n1 * ct + n2 * ci)
            geom = (n2 * ct) / (n1 * ci)
            rs, rp, cos_t = fresnel_dielectric_sp(ci, n2 / n1)
            assert cos_t == pytest.approx(ct, rel=1e-12)
            assert rs + geom * ts * ts == pytest.approx(1.0, abs=1e-13)
            assert rp + geom * tp * tp == pytest.approx(1.0, abs=1e-13)


# --- directions -----------------------------------------------------------------------------------


@pytest.mark.parametrize("n", IORS)
def test_refract_obeys_snell(n):
    nv = np.asarray(N_WORLD)
    for n1, n2 in ((1.0, n), (n, 1.0)):
        limit = math.asin(n2 / n1) if n1 > n2 else math.pi / 2
        for theta in np.linspace(0.0, limit - 1e-3, 25):
            wo = direction_at(nv, theta)
            f, cos_t = fresnel_dielectric(math.cos(theta), n2 / n1)
            wt = np.asarray(refract(wo, N_WORLD, n2 / n1, math.cos(theta), cos_t))
            assert np.linalg.norm(wt) == pytest.approx(1.0, abs=1e-14)
            assert wt @ nv < 0.0  # on the other side
            sin_t = np.linalg.norm(np.cross(wt, nv))
            assert n1 * math.sin(theta) == pytest.approx(n2 * sin_t, abs=1e-14)
            assert wt @ np.cross(wo, nv) == pytest.approx(0.0, abs=1e-14)  # plane of incidence
            tan_o = np.asarray(wo) - (np.asarray(wo) @ nv) * nv
            tan_t = wt - (wt @ nv) * nv
            assert tan_o @ tan_t <= 1e-15  # the tangential part flips: wo points away


def test_reflect():
    nv = np.asarray(N_WORLD)
    for theta in (0.0, 0.3, 1.2, 1.55):
        wo = np.asarray(direction_at(nv, theta))
        wr = np.asarray(reflect(tuple(wo), N_WORLD))
        assert wr @ nv == pytest.approx(wo @ nv, abs=1e-15)  # same side, same angle
        np.testing.assert_allclose(wr + wo, 2.0 * (wo @ nv) * nv, atol=1e-15)


# --- the dielectric sampler -----------------------------------------------------------------------

IOR = 1.5


@pytest.mark.parametrize("theta_deg,outside", [(0.0, True), (60.0, True), (85.0, True),
                                                (30.0, False), (41.0, False), (50.0, False)])
def test_dielectric_sample_frequencies(rng, theta_deg, outside):
    # Reflection is chosen with probability F: over N uniform uc the count of reflections is
    # Binomial(N, F), checked to 5σ = 5√(N F (1 − F)) (plus 1 for F ∈ {0, 1}). Every reflection
    # is the mirror direction with weight 1, every refraction Snell's direction with weight
    # 1/η², η = η_t/η_i (radiance scales by η² across the interface).
    n_samples = 40_000
    theta = math.radians(theta_deg)
    nv = np.asarray(N_WORLD)
    wo = direction_at(nv if outside else -nv, theta)
    eta = IOR if outside else 1.0 / IOR
    f, cos_t = fresnel_dielectric(math.cos(theta), eta)
    param = np.zeros(12)
    param[0] = IOR
    out = [dielectric_sample(param, wo, N_WORLD, uc) for uc in rng.random(n_samples)]
    wi = np.array([o[0] for o in out])
    weight = np.array([o[1] for o in out])
    reflected = (wi @ nv > 0.0) == (np.dot(wo, nv) > 0.0)
    n_reflect = int(reflected.sum())
    assert np.all(weight[reflected] == 1.0)
    np.testing.assert_allclose(weight[~reflected], 1.0 / (eta * eta), rtol=1e-15)
    np.testing.assert_allclose(wi[reflected], np.broadcast_to(reflect(wo, N_WORLD), (n_reflect, 3)),
                               atol=1e-15)
    sin_t = np.linalg.norm(np.cross(wi[~reflected], nv), axis=1)
    np.testing.assert_allclose(eta * sin_t, math.sin(theta), atol=1e-13)  # Snell
    sigma = math.sqrt(n_samples * f * (1.0 - f))
    assert abs(n_reflect - n_samples * f) <= 5.0 * sigma + 1.0
    if theta_deg == 50.0:  # beyond the critical angle 41.8°: total internal reflection
        assert n_reflect == n_samples
    # The binomial test above cannot see F off by ~2 % when F is small; stratified uc can: with
    # uc = (i + ½)/M the share of reflections is exactly F to within 1/M.
    m = 20_000
    stratified = [dielectric_sample(param, wo, N_WORLD, (i + 0.5) / m)[0] for i in range(m)]
    share = np.mean((np.asarray(stratified) @ nv > 0.0) == (np.dot(wo, nv) > 0.0))
    assert abs(share - f) <= 1.0 / m


def test_dielectric_sample_directions():
    param = np.zeros(12)
    param[0] = IOR
    nv = np.asarray(N_WORLD)
    wo = direction_at(nv, 0.7)
    wi, weight = dielectric_sample(param, wo, N_WORLD, 0.0)  # uc < F: reflection
    np.testing.assert_allclose(wi, reflect(wo, N_WORLD), atol=1e-15)
    wi, weight = dielectric_sample(param, wo, N_WORLD, 0.999999)  # refraction into the glass
    assert np.dot(wi, nv) < 0.0 and weight == pytest.approx(1.0 / IOR**2)
    wo_in = direction_at(-nv, 0.3)  # from inside, leaving: weight η² = 1.5²
    wi, weight = dielectric_sample(param, wo_in, N_WORLD, 0.999999)
    assert np.dot(wi, nv) > 0.0 and weight == pytest.approx(IOR**2)
