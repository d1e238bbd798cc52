"""Normalized Phong (renderer/materials/phong.py): energy, reciprocity, and the diffuse furnace.

The directional albedo ρ(wo) = ∫ f(wo, wi) cos θi dωi is computed by quadrature about the normal:
Gauss–Legendre in cos θi (the horizon is an end point, the lobe meets its cut-off cos α = 0 as
cosⁿα, i.e. smoothly) and the midpoint rule in φ, which is spectrally accurate for a periodic
integrand. At normal incidence the integrand is a polynomial in cos θi of degree n + 1, which
Gauss–Legendre with 512 nodes integrates exactly for n ≤ 1021; elsewhere the default rule (256 × 512
nodes) is checked against a 4× finer one in ``test_quadrature_converged``.

Closed form at normal incidence (wo = n, so α = θi): the specular albedo is
    ks ∫₀^{2π} ∫₀^{π/2} (n + 2)/(2π) cosⁿθ · cos θ sin θ dθ dφ = ks (n + 2) ∫₀¹ μⁿ⁺¹ dμ = ks,
exactly — the (n + 2)/(2π) normalization (Lafortune & Willems 1994). A lobe normalized by
(n + 1)/(2π) instead would give ks (n + 1)/(n + 2), which these tests tell apart.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.jit import alloc_kernel
from renderer.materials.diffuse import diffuse_eval
from renderer.materials.phong import phong_eval, phong_sample
from tests.conftest import phong_param

NORMAL = tuple(np.array([-0.4, 0.1, 0.9]) / np.linalg.norm([-0.4, 0.1, 0.9]))


@alloc_kernel
def _albedo(param, wo, n, t, b, mu, mu_w, n_phi, diffuse):
    """ρ(wo) per channel: Σ over Gauss–Legendre nodes mu (weights mu_w, on [0, 1]) × n_phi
    midpoints of φ of eval(wo, wi), wi = sinθ(cosφ t + sinφ b) + cosθ n."""
    acc = np.zeros(3)
    dphi = 2.0 * math.pi / n_phi
    for i in range(mu.shape[0]):
        c = mu[i]
        s = math.sqrt(max(0.0, 1.0 - c * c))
        for j in range(n_phi):
            phi = (j + 0.5) * dphi
            cp, sp = s * math.cos(phi), s * math.sin(phi)
            wi = (cp * t[0] + sp * b[0] + c * n[0],
                  cp * t[1] + sp * b[1] + c * n[1],
                  cp * t[2] + sp * b[2] + c * n[2])
            f = diffuse_eval(param, wo, wi, n) if diffuse else phong_eval(param, wo, wi, n)
            for k in range(3):
                acc[k] += mu_w[i] * f[k]
    return acc * dphi


@alloc_kernel
def _mean_weight(param, wo, n, u):
    """Mean and per-channel variance of phong_sample's weight over the rows (uc, u1, u2) of u;
    a refused sample weighs 0."""
    m = u.shape[0]
    w = np.zeros((m, 3))
    for i in range(m):
        _, weight, _, ok = phong_sample(param, wo, n, u[i, 0], u[i, 1], u[i, 2])
        if ok:
            for k in range(3):
                w[i, k] = weight[k]
    return w


def basis(n):
    n = np.asarray(n)
    t = np.cross(n, [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    return tuple(t), tuple(np.cross(n, t))


def albedo(param, wo, n=NORMAL, n_mu=256, n_phi=512, diffuse=False) -> np.ndarray:
    x, w = np.polynomial.legendre.leggauss(n_mu)
    t, b = basis(n)
    return _albedo(param, tuple(wo), n, t, b, 0.5 * (x + 1.0), 0.5 * w, n_phi, diffuse)


def at_angle(theta, n=NORMAL):
    t, _ = basis(n)
    return tuple(math.sin(theta) * np.asarray(t) + math.cos(theta) * np.asarray(n))



@pytest.mark.parametrize("exponent", [0.0, 1.0, 10.0, 100.0, 1000.0, 7.5])
def test_specular_albedo_at_normal_incidence_is_ks(exponent):
    # Exact for the integer exponents (polynomial integrand); 7.5 is smooth, GL converges fast.
    ks = np.array([0.2, 0.5, 0.9])
    rho = albedo(phong_param([0, 0, 0], ks, exponent), NORMAL, n_mu=512, n_phi=64)
    np.testing.assert_allclose(rho, ks, rtol=1e-10)


@pytest.mark.parametrize("exponent", [1.0, 10.0, 100.0])
def test_albedo_never_exceeds_kd_plus_ks(exponent):
    # For every wo the surface reflects at most kd + ks (≤ 1 per channel, as the schema checks):
    # the lobe loses its part below the horizon and cos θi < cos α weights it down. The specular
    # part alone stays ≤ ks and the diffuse part is kd whatever wo is. Tolerance 1e-6: above the
    # quadrature error (< 4e-7, test_quadrature_converged), far below a normalization error.
    kd = np.array([0.5, 0.3, 0.1])
    ks = np.array([0.5, 0.7, 0.9])
    for theta_deg in (0, 10, 30, 45, 60, 75, 85, 89.5):
        wo = at_angle(math.radians(theta_deg))
        rho = albedo(phong_param(kd, ks, exponent), wo)
        spec = albedo(phong_param([0, 0, 0], ks, exponent), wo)
        diff = albedo(phong_param(kd, [0, 0, 0], exponent), wo, n_phi=64)
        assert np.all(rho <= kd + ks + 1e-6), (theta_deg, rho)
        assert np.all(spec <= ks + 1e-6), (theta_deg, spec)
        np.testing.assert_allclose(diff, kd, rtol=1e-12)
        np.testing.assert_allclose(rho, diff + spec, rtol=1e-12)
        if theta_deg >= 30:
            assert np.all(spec < ks * 0.999)  # strictly less once the lobe is tilted


@pytest.mark.parametrize("exponent", [10.0, 100.0])
def test_specular_albedo_at_oblique_incidence(exponent):
    # Closed form with a bound: write wi·n = cos α (r·n) + (terms odd about r), so over the whole
    # lobe ∫_{cos α > 0} (n + 2)/(2π) cosⁿα (wi·n) dω = cos θo. eval drops the part of the lobe
    # below the horizon, where wi·n < 0, so the albedo is cos θo plus that part's |wi·n|-weighted
    # mass, which is at most (n + 2)/(n + 1)·P(α > 90° − θo) = (n + 2)/(n + 1)·sin^(n+1) θo:
    #   ks cos θo ≤ ρ_spec(θo) ≤ ks [cos θo + (n + 2)/(n + 1) sin^(n+1) θo].
    ks = np.array([0.25, 0.5, 1.0])
    for theta_deg in (20, 45, 60, 75, 85):
        th = math.radians(theta_deg)
        rho = albedo(phong_param([0, 0, 0], ks, exponent), at_angle(th))
        below = (exponent + 2.0) / (exponent + 1.0) * math.sin(th) ** (exponent + 1.0)
        assert np.all(rho >= ks * math.cos(th) - 1e-7), (theta_deg, rho)
        assert np.all(rho <= ks * (math.cos(th) + below) + 1e-7), (theta_deg, rho)


def test_quadrature_converged():
    # The default rule against one 4× finer in each variable, for the lobes used above at the
    # angles where they are hardest to integrate (n = 1 has a kink at the horizon, n = 100 is
    # narrow): they agree to 1e-6, so the 1e-6 tolerances are not eaten by quadrature error.
    for exponent, theta_deg in ((1.0, 89.5), (1.0, 60.0), (100.0, 60.0), (100.0, 85.0)):
        param = phong_param([0, 0, 0], [1, 1, 1], exponent)
        wo = at_angle(math.radians(theta_deg))
        coarse = albedo(param, wo)
        fine = albedo(param, wo, n_mu=1024, n_phi=2048)
        np.testing.assert_allclose(coarse, fine, atol=1e-6)


def test_diffuse_furnace():
    # A white furnace: a Lambertian surface of albedo kd under unit radiance from every direction
    # reflects exactly kd, for any wo; the Phong model with ks = 0 does the same.
    kd = np.array([1.0, 0.6, 0.25])
    for theta_deg in (0, 40, 80):
        wo = at_angle(math.radians(theta_deg))
        np.testing.assert_allclose(albedo(phong_param(kd, [0, 0, 0], 5), wo, n_phi=64,
                                          diffuse=True), kd, rtol=1e-12)
        np.testing.assert_allclose(albedo(phong_param(kd, [0, 0, 0], 5), wo, n_phi=64), kd,
                                   rtol=1e-12)


@pytest.mark.parametrize("exponent,theta_deg", [(10.0, 0.0), (10.0, 60.0), (200.0, 30.0)])
def test_sampled_weights_estimate_the_albedo(rng, exponent, theta_deg):
    # E[weight] of phong_sample is ∫ f cos dωi (refused samples weigh 0): the Monte Carlo mean
    # over N samples agrees with the quadrature to 5 standard errors of the mean. This ties
    # sample, pdf and eval together: any inconsistency between them biases the mean.
    param = phong_param([0.3, 0.2, 0.1], [0.6, 0.5, 0.4], exponent)
    wo = at_angle(math.radians(theta_deg))
    n = 400_000
    w = _mean_weight(param, wo, NORMAL, rng.random((n, 3)))
    mean, sem = w.mean(axis=0), w.std(axis=0) / math.sqrt(n)
    rho = albedo(param, wo)
    assert np.all(np.abs(mean - rho) < 5.0 * sem + 1e-9), (mean, rho, sem)


def test_reciprocity(rng):
    # f(wo, wi) = f(wi, wo), with f = eval/cos θi, for random pairs above the surface.
    param = phong_param([0.3, 0.2, 0.1], [0.6, 0.5, 0.4], 20.0)
    nv = np.asarray(NORMAL)
    pairs = 0
    for _ in range(2000):
        a, b = rng.normal(size=(2, 3))
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        a, b = a * np.sign(a @ nv), b * np.sign(b @ nv)
        fab = np.asarray(phong_eval(param, tuple(a), tuple(b), NORMAL)) / (b @ nv)
        fba = np.asarray(phong_eval(param, tuple(b), tuple(a), NORMAL)) / (a @ nv)
        np.testing.assert_allclose(fab, fba, rtol=1e-11)
        pairs += bool(np.any(fab != np.asarray(param[0:3]) / np.pi))  # the lobe contributed
    assert pairs > 100  # not only the diffuse part compared


def test_eval_below_the_surface_is_zero():
    param = phong_param([0.3, 0.2, 0.1], [0.6, 0.5, 0.4], 20.0)
    wo = at_angle(0.4)
    below = tuple(-np.asarray(at_angle(0.7)))
    assert phong_eval(param, wo, below, NORMAL) == (0.0, 0.0, 0.0)
