"""Christensen–Burley normalized diffusion (renderer/materials/burley.py): normalization, CDF,
exact inversion, sampling (chi²) and moments.

Closed forms the tests check against. The radial density p(r) = 2πr R(r) =
(e^{−r/d} + e^{−r/(3d)})/(4d) is the mixture ¼·Exp(mean d) + ¾·Exp(mean 3d), so

    E[r] = ¼·d + ¾·3d = 5d/2,    E[r²] = ¼·2d² + ¾·2(3d)² = 14d²,    Var r = 31d²/4,

and near r = 0, P(r) = r/(2d) − r²/(6d²) + O(r³), whence r(u) = 2du + 4du²/3 + O(u³).

Tolerances: quadratures (scipy's adaptive Gauss–Kronrod on smooth integrands) agree with the
closed forms to ~1e-14, so 1e-10 leaves room without hiding a wrong constant (a missing factor or
a swapped ¼/¾ is off by O(1)). The inversion is checked in *relative* terms, on P for u < ½ and on
1 − P for u ≥ ½, so both tails are held to 1e-12 of what they are, not of 1. The chi² tests use
N = 400 000 samples, every cell expecting at least ~25; a width d off by 3 % moves the radial
statistic by ~N·(0.03)²·O(1) ≈ 400 over a spread of √(2·100) ≈ 14, far past the Bonferroni
threshold of tests/conftest.py, while a correct sampler passes with probability ≥ 1 − 1/6000.
The sampled mean is held to 5σ of its standard error √(31/4)·d/√N (a false alarm rate of 6e-7).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, optimize

from renderer.jit import alloc_kernel
from renderer.materials.burley import (
    burley_cdf,
    burley_d,
    burley_pdf_area,
    burley_pdf_radius,
    burley_profile,
    burley_r_max,
    burley_s,
    burley_sample_point,
    burley_sample_radius,
)

N = 400_000  # samples per chi² and moment test (see the module docstring)
WIDTHS = (1.0, 0.0137, 42.0)  # d: unit, small and large scene scales

# Every u the inversion is checked at: both ends to the last double, and a sweep between.
U_EDGES = (0.0, 1e-300, 1e-17, 1e-12, 1e-8, 1e-4, 0.5 - 2**-54, 0.5, 1.0 - 1e-16,
           1.0 - 2**-53, 1.0 - 2**-52, 1.0 - 1e-12, 1.0 - 1e-6)
U_ALL = np.concatenate([U_EDGES, np.linspace(0.0, 1.0, 1001)[:-1], np.geomspace(1e-15, 0.5, 200),
                        1.0 - np.geomspace(1e-15, 0.5, 200)])


# --- numba loops and NumPy references -------------------------------------------------------------


@alloc_kernel
def _radii(u, d):
    out = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        out[i] = burley_sample_radius(u[i], d)
    return out


@alloc_kernel
def _points(u, d):
    out = np.empty((u.shape[0], 2))
    for i in range(u.shape[0]):
        x, y, _ = burley_sample_point(u[i, 0], u[i, 1], d)
        out[i, 0] = x
        out[i, 1] = y
    return out


@alloc_kernel
def _pdf_area_many(p, d):
    out = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        out[i] = burley_pdf_area(math.sqrt(p[i, 0] * p[i, 0] + p[i, 1] * p[i, 1]), d)
    return out


def ref_cdf(r, d):
    """P(r), NumPy, with expm1 so that it is accurate for r ≪ d."""
    return -0.25 * (np.expm1(-r / d) + 3.0 * np.expm1(-r / (3.0 * d)))


def ref_ccdf(r, d):
    """1 − P(r), NumPy, accurate in the tail."""
    return 0.25 * np.exp(-r / d) + 0.75 * np.exp(-r / (3.0 * d))


# --- the profile and its densities ---------------------------------------------------------------


@pytest.mark.parametrize("d", WIDTHS)
def test_profile_integrates_to_one(d):
    """∫₀^∞ R(r) 2πr dr = 1: the profile is normalized over the plane."""
    total, err = integrate.quad(lambda r: 2.0 * math.pi * r * burley_profile(r, d), 0.0, np.inf,
                                epsabs=1e-13, epsrel=1e-13, limit=200)
    assert abs(total - 1.0) < 1e-10, (total, err)


@pytest.mark.parametrize("d", WIDTHS)
def test_profile_values(d):
    """R(r) against the formula written out, and the two densities against R."""
    for r in np.array([1e-6, 0.01, 0.3, 1.0, 2.5, 10.0, 60.0]) * d:
        expected = (math.exp(-r / d) + math.exp(-r / (3.0 * d))) / (8.0 * math.pi * d * r)
        assert burley_profile(r, d) == pytest.approx(expected, rel=1e-13)
        assert burley_pdf_area(r, d) == pytest.approx(expected, rel=1e-13)
        assert burley_pdf_radius(r, d) == pytest.approx(2.0 * math.pi * r * expected, rel=1e-13)
    assert burley_pdf_radius(0.0, d) == pytest.approx(0.5 / d, rel=1e-15)  # p(0) = 1/(2d)
    assert burley_pdf_radius(-1.0, d) == 0.0
    assert burley_profile(0.0, d) == math.inf  # the integrable 1/r singularity at the origin


@pytest.mark.parametrize("d", WIDTHS)
def test_cdf_is_the_integral_of_the_pdf(d):
    for r in np.array([1e-9, 1e-3, 0.1, 0.5, 1.0, 2.0, 5.0, 13.0, 30.0, 80.0]) * d:
        integral, _ = integrate.quad(lambda t: burley_pdf_radius(t, d), 0.0, r,
                                     epsabs=1e-15, epsrel=1e-13, limit=200)
        assert burley_cdf(r, d) == pytest.approx(integral, rel=1e-11, abs=1e-14), r
        assert burley_cdf(r, d) == pytest.approx(ref_cdf(r, d), rel=1e-14, abs=1e-16)
    assert burley_cdf(0.0, d) == 0.0
    assert burley_cdf(-d, d) == 0.0
    assert burley_cdf(math.inf, d) == 1.0
    # Relative precision near 0, where 1 − e^{−r/d}/4 − … would round to 0: P(r) ≈ r/(2d).
    assert burley_cdf(1e-200 * d, d) == pytest.approx(0.5e-200, rel=1e-14)


# --- inverting the CDF ----------------------------------------------------------------------------


@pytest.mark.parametrize("d", WIDTHS)
def test_sample_radius_inverts_the_cdf(d):
    """P(r(u)) = u to 1e-12 relative for u < ½, and 1 − P(r(u)) = 1 − u likewise for u ≥ ½."""
    r = _radii(U_ALL, d)
    assert np.all(np.isfinite(r)) and np.all(r >= 0.0)
    assert not np.any(np.signbit(r)), "r = −0.0"
    low = U_ALL < 0.5
    u_lo, r_lo = U_ALL[low], r[low]
    np.testing.assert_allclose(ref_cdf(r_lo, d), u_lo, rtol=1e-12, atol=0.0)
    w_hi = 1.0 - U_ALL[~low]  # exact for u ≥ ½ (Sterbenz)
    np.testing.assert_allclose(ref_ccdf(r[~low], d), w_hi, rtol=1e-12, atol=0.0)
    # And the kernel's own CDF agrees (absolute: it is 1 − small for large r).
    cdf = np.array([burley_cdf(x, d) for x in r])
    np.testing.assert_allclose(cdf, U_ALL, rtol=0.0, atol=1e-15)
    # Monotone in u, as an inversion must be.
    u_sorted = np.sort(U_ALL)
    assert np.all(np.diff(_radii(u_sorted, d)) >= 0.0)


@pytest.mark.parametrize("d", WIDTHS)
def test_sample_radius_matches_root_finding(d):
    """r(u) against Brent's method on P (or 1 − P) to 1e-12 relative."""
    for u in np.concatenate([np.geomspace(1e-12, 0.49, 25), 1.0 - np.geomspace(1e-15, 0.5, 25)]):
        if u < 0.5:
            ref = optimize.brentq(lambda x, u=u: ref_cdf(x, d) - u, 0.0, 200.0 * d,
                                  xtol=1e-300, rtol=8.9e-16, maxiter=500)
        else:
            w = 1.0 - u
            ref = optimize.brentq(lambda x, w=w: ref_ccdf(x, d) - w, 0.0, 200.0 * d,
                                  xtol=1e-300, rtol=8.9e-16, maxiter=500)
        assert burley_sample_radius(u, d) == pytest.approx(ref, rel=1e-12), u


@pytest.mark.parametrize("d", WIDTHS)
def test_sample_radius_ends(d):
    """u → 0: r = 2du + 4du²/3 + O(u³) (series of P); u → 1: finite; u = 0 → 0; u = 1 → inf."""
    assert burley_sample_radius(0.0, d) == 0.0
    # The smallest subnormal: r = 2du rounds to a subnormal or 0, but never NaN or negative.
    r_sub = burley_sample_radius(5e-324, d)
    assert 0.0 <= r_sub <= 4.0 * d * 5e-324
    for u in (1e-300, 1e-100, 1e-17, 1e-9, 1e-7):
        assert burley_sample_radius(u, d) == pytest.approx(2.0 * d * u * (1.0 + 2.0 * u / 3.0),
                                                           rel=1e-12), u
    r_top = burley_sample_radius(1.0 - 2**-53, d)  # the largest double below 1
    # 1 − P ≈ ¾ e^{−r/(3d)} in the tail: r ≈ 3d ln(¾ · 2⁵³) ≈ 109.3d.
    assert r_top == pytest.approx(3.0 * d * math.log(0.75 * 2.0**53), rel=1e-12)
    assert burley_sample_radius(1.0, d) == math.inf


# --- sampling: chi² and moments -------------------------------------------------------------------


@pytest.mark.parametrize("d", (1.0, 0.0137))
def test_sample_radius_chi2(rng, chi2_counts, d):
    """Histogram of r(u), u uniform, against ∫ p(r) dr over 100 bins of [0, r_max] (+ the tail)."""
    r = _radii(rng.random(N), d)
    edges = np.linspace(0.0, burley_r_max(d, 0.999), 101)
    counts, _ = np.histogram(r, bins=edges)
    probs = np.array([integrate.quad(lambda t: burley_pdf_radius(t, d), a, b,
                                     epsabs=1e-14, epsrel=1e-12)[0]
                      for a, b in zip(edges[:-1], edges[1:], strict=True)])
    assert probs.sum() < 1.0
    observed = np.append(counts, N - counts.sum())
    expected = np.append(probs, 1.0 - probs.sum()) * N
    chi2_counts(observed, expected, f"burley_sample_radius(d = {d})")


def test_sample_point_chi2(rng, chi2_points):
    """Points (r cos φ, r sin φ) against the claimed area density R(|p|) on a grid beside the
    origin (the grid's midpoint quadrature cannot integrate the 1/r singularity at the origin
    itself; samples off the grid, near the origin included, are counted in the rest cell)."""
    d = 0.7
    chi2_points(lambda n: _points(rng.random((n, 2)), d), lambda p: _pdf_area_many(p, d), N,
                bounds=((0.2 * d, 3.2 * d), (-1.5 * d, 1.5 * d)), shape=(20, 20),
                what="burley_sample_point")


@pytest.mark.parametrize("d", (1.0, 0.0137))
def test_mean_radius(rng, d):
    """E[r] = 5d/2 and E[r²] = 14d² by quadrature, and the sampled mean within 5σ of 5d/2."""
    mean, _ = integrate.quad(lambda t: t * burley_pdf_radius(t, d), 0.0, np.inf, epsrel=1e-13)
    second, _ = integrate.quad(lambda t: t * t * burley_pdf_radius(t, d), 0.0, np.inf,
                               epsrel=1e-13)
    assert mean == pytest.approx(2.5 * d, rel=1e-10)
    assert second == pytest.approx(14.0 * d * d, rel=1e-10)
    r = _radii(rng.random(N), d)
    sigma = math.sqrt(31.0 / 4.0) * d / math.sqrt(N)
    assert abs(r.mean() - 2.5 * d) < 5.0 * sigma, (r.mean(), 2.5 * d, sigma)


# --- parameters -----------------------------------------------------------------------------------


def test_shape_factor():
    """s(A) = 1.85 − A + 7|A − 0.8|³ (eq. 5): 1.85 + 7·0.8³ = 5.434 at A = 0, 1.05 at the kink
    A = 0.8, 1.85 − 1 + 7·0.2³ = 0.906 at A = 1."""
    assert burley_s(0.0) == pytest.approx(5.434, abs=1e-14)
    assert burley_s(0.8) == pytest.approx(1.05, abs=1e-14)
    assert burley_s(1.0) == pytest.approx(0.906, abs=1e-14)
    assert burley_s(0.5) == pytest.approx(1.85 - 0.5 + 7.0 * 0.3**3, abs=1e-14)  # |·|: A < 0.8
    for a in (0.0, 0.3, 0.8, 1.0):
        assert burley_d(a, 2.0) == pytest.approx(2.0 / burley_s(a), rel=1e-15)


@pytest.mark.parametrize("d", WIDTHS)
def test_r_max(d):
    """P(r_max(q)) = q; the default quantile is 0.999, where 1 − P is ¾e^{−r/(3d)} + ¼e^{−r/d}."""
    for q in (0.5, 0.9, 0.99, 0.999, 0.999999):
        assert burley_cdf(burley_r_max(d, q), d) == pytest.approx(q, rel=1e-13)
    assert burley_r_max(d) == burley_r_max(d, 0.999)
    assert ref_ccdf(burley_r_max(d), d) == pytest.approx(1e-3, rel=1e-12)
    assert burley_r_max(d) == pytest.approx(19.86022139736621 * d, rel=1e-12)
