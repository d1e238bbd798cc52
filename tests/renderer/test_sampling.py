"""Every sampling routine draws what its pdf says: chi² tests (tests/conftest.py) and moments.

The routines are the warps of ``renderer/sampling.py``, the BSDF samplers of the diffuse and
Phong materials and the light sampler of ``renderer/lights.py``. Each chi² test compares the
histogram of N samples with the integral of the *claimed* density over the same cells, so a sampler
and a pdf that disagree — in shape, normalization or dropped samples — fail it. The cell counts
and N = 400 000 are chosen so that every cell expects hundreds of samples.

Power: a density off by a relative δ over a share s of the sphere adds about N·s·δ² to the
statistic, whose spread is √(2·dof) ≈ 40 for ~800 cells. δ = 3 % everywhere adds ~360 (9σ,
p ~ 1e-15: caught with probability > 0.9999 at the Bonferroni threshold of tests/conftest.py);
δ = 3 % over a tenth of the sphere adds only ~36 (1σ). So these tests catch errors of a few per
cent over much of the domain — a wrong exponent, normalization, Jacobian or mixture weight — not
sub-per-cent ones.

The samples are drawn by small numba loops (the renderer's kernels called from Python cost about a
microsecond each) that only call the kernel under test and store what it returns.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.environment import no_environment
from renderer.geometry.shapes import QUAD, SPHERE, TRIANGLE, intersect_prim, surface_point
from renderer.jit import alloc_kernel
from renderer.lights import AREA, BACKGROUND, POINT, area_light_pdf, sample_light
from renderer.materials.bsdf import DIFFUSE, PHONG, bsdf_eval, bsdf_pdf, bsdf_sample
from renderer.sampling import (
    cosine_hemisphere,
    cosine_hemisphere_pdf,
    phong_lobe,
    phong_lobe_pdf,
    sample_discrete,
    uniform_cone,
    uniform_cone_pdf,
    uniform_sphere,
    uniform_triangle,
)
from tests.conftest import phong_param

N = 400_000  # samples per chi² test (see the module docstring for the power this gives)

COSINE, SPHERE_WARP, CONE, PHONG_LOBE = 0, 1, 2, 3


# --- numba loops: call one kernel N times --------------------------------------------------------


@alloc_kernel
def _warp_many(which, u, param):
    n = u.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        if which == COSINE:
            w = cosine_hemisphere(u[i, 0], u[i, 1])
        elif which == SPHERE_WARP:
            w = uniform_sphere(u[i, 0], u[i, 1])
        elif which == CONE:
            w = uniform_cone(u[i, 0], u[i, 1], param)
        else:
            w = phong_lobe(u[i, 0], u[i, 1], param)
        out[i, 0] = w[0]
        out[i, 1] = w[1]
        out[i, 2] = w[2]
    return out


@alloc_kernel
def _warp_pdf_many(which, w, param):
    """The renderer's own pdf of each direction (about +z)."""
    n = w.shape[0]
    out = np.empty(n)
    for i in range(n):
        if which == COSINE:
            out[i] = cosine_hemisphere_pdf(w[i, 2])
        elif which == SPHERE_WARP:
            out[i] = 1.0 / (4.0 * math.pi)
        elif which == CONE:
            out[i] = uniform_cone_pdf(param) if 1.0 - w[i, 2] <= param else 0.0
        else:
            out[i] = phong_lobe_pdf(w[i, 2], param)
    return out


@alloc_kernel
def _triangle_many(u):
    n = u.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        b1, b2 = uniform_triangle(u[i, 0], u[i, 1])
        out[i, 0] = b1
        out[i, 1] = b2
    return out


@alloc_kernel
def _discrete_many(cdf, u):
    out = np.empty(u.shape[0], np.int64)
    for i in range(u.shape[0]):
        out[i] = sample_discrete(cdf, u[i])
    return out


@alloc_kernel
def _bsdf_sample_many(kind, param, wo, n, u):
    """wi (NaN where ok is False), weight, pdf and ok of bsdf_sample for each row (uc, u1, u2)."""
    m = u.shape[0]
    wi_out = np.empty((m, 3))
    weight = np.zeros((m, 3))
    pdf = np.zeros(m)
    ok = np.zeros(m, np.bool_)
    for i in range(m):
        wi, w, p, good = bsdf_sample(kind, param, wo, n, u[i, 0], u[i, 1], u[i, 2])
        ok[i] = good
        if good:
            for j in range(3):
                wi_out[i, j] = wi[j]
                weight[i, j] = w[j]
            pdf[i] = p
        else:
            for j in range(3):
                wi_out[i, j] = np.nan
    return wi_out, weight, pdf, ok


@alloc_kernel
def _bsdf_eval_pdf_many(kind, param, wo, n, wi):
    """bsdf_eval (f·cos θi) and bsdf_pdf for each row of wi."""
    m = wi.shape[0]
    f = np.empty((m, 3))
    pdf = np.empty(m)
    for i in range(m):
        w = (wi[i, 0], wi[i, 1], wi[i, 2])
        e = bsdf_eval(kind, param, wo, w, n)
        f[i, 0] = e[0]
        f[i, 1] = e[1]
        f[i, 2] = e[2]
        pdf[i] = bsdf_pdf(kind, param, wo, w, n)
    return f, pdf


NO_ENVIRONMENT = no_environment()


def _light_sample_many(light_kind, light_prim, light_data, light_cdf, light_pmf, prim_kind,
                       prim_geo, p, u):
    return _light_sample_env_many(light_kind, light_prim, light_data, light_cdf, light_pmf,
                                  prim_kind, prim_geo, *NO_ENVIRONMENT, p, u)


@alloc_kernel
def _light_sample_env_many(light_kind, light_prim, light_data, light_cdf, light_pmf, prim_kind,
                           prim_geo, env_image, env_marginal, env_conditional, env_rotation, p, u):
    m = u.shape[0]
    wi_out = np.empty((m, 3))
    li_out = np.empty((m, 3))
    pdf = np.empty(m)
    t_max = np.empty(m)
    delta = np.empty(m, np.bool_)
    for i in range(m):
        wi, li, pd, t, d = sample_light(light_kind, light_prim, light_data, light_cdf, light_pmf,
                                        prim_kind, prim_geo, env_image, env_marginal,
                                        env_conditional, env_rotation, p, u[i, 0], u[i, 1],
                                        u[i, 2])
        for j in range(3):
            wi_out[i, j] = wi[j]
            li_out[i, j] = li[j]
        pdf[i] = pd
        t_max[i] = t
        delta[i] = d
    return wi_out, li_out, pdf, t_max, delta


@alloc_kernel
def _area_light_pdf_many(light_pmf, li, kind, geo, p, w):
    """area_light_pdf of the point each direction w reaches on the light (0 where it misses)."""
    m = w.shape[0]
    out = np.zeros(m)
    for i in range(m):
        d = (w[i, 0], w[i, 1], w[i, 2])
        t, u, v = intersect_prim(kind, p, d, geo)
        if t < np.inf:
            q, nq = surface_point(kind, geo, p, d, t, u, v)
            out[i] = area_light_pdf(light_pmf, li, kind, geo, p, q, nq)
    return out


@alloc_kernel
def _area_light_pdf_at(light_pmf, li, kind, geo, p, wi, t):
    """area_light_pdf at the points p + t·wi the light sampler chose, normals from the shape."""
    m = wi.shape[0]
    out = np.empty(m)
    for i in range(m):
        d = (wi[i, 0], wi[i, 1], wi[i, 2])
        q = (p[0] + t[i] * d[0], p[1] + t[i] * d[1], p[2] + t[i] * d[2])
        if kind == SPHERE:
            nq = ((q[0] - geo[0]) / geo[3], (q[1] - geo[1]) / geo[3], (q[2] - geo[2]) / geo[3])
        else:
            nx = geo[4] * geo[8] - geo[5] * geo[7]
            ny = geo[5] * geo[6] - geo[3] * geo[8]
            nz = geo[3] * geo[7] - geo[4] * geo[6]
            ln = math.sqrt(nx * nx + ny * ny + nz * nz)
            nq = (nx / ln, ny / ln, nz / ln)
        out[i] = area_light_pdf(light_pmf, li, kind, geo, p, q, nq)
    return out


# --- helpers --------------------------------------------------------------------------------------


def vec(a) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def unit(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a / np.linalg.norm(a)



def lobe_edges(exponent: float, n_cos: int = 20) -> np.ndarray:
    """cos θ cells for a cosⁿ lobe: equal steps of 1 − cos θ up to where the lobe has e^-10 of its
    mass left, so that a narrow lobe is resolved by every cell (the rest goes to the rest cell)."""
    x_max = min(2.0, 10.0 / (exponent + 1.0))
    return 1.0 - np.linspace(x_max, 0.0, n_cos + 1)


def oblique(n, theta_deg: float) -> tuple[float, float, float]:
    """A unit direction at θ from the unit normal n."""
    n = unit(n)
    t = unit(np.cross(n, [0.3, 0.9, 0.1]))
    th = math.radians(theta_deg)
    return vec(math.sin(th) * t + math.cos(th) * n)


# --- warps of the unit square ---------------------------------------------------------------------


def test_cosine_hemisphere_chi2(rng, chi2_directions):
    chi2_directions(lambda n: _warp_many(COSINE, rng.random((n, 2)), 0.0),
                    lambda w: np.maximum(w[:, 2], 0.0) / np.pi, N, what="cosine_hemisphere")


def test_uniform_sphere_chi2(rng, chi2_directions):
    chi2_directions(lambda n: _warp_many(SPHERE_WARP, rng.random((n, 2)), 0.0),
                    lambda w: np.full(len(w), 1.0 / (4.0 * np.pi)), N, what="uniform_sphere")


@pytest.mark.parametrize("omc", [0.05, 0.7, 1.6])
def test_uniform_cone_chi2(rng, chi2_directions, omc):
    # Cells cover exactly the cone (cos θ from 1 − omc to 1): a direction outside it lands in the
    # rest cell, which expects nothing.
    pdf = 1.0 / (2.0 * np.pi * omc)
    chi2_directions(lambda n: _warp_many(CONE, rng.random((n, 2)), omc),
                    lambda w: np.where(1.0 - w[:, 2] <= omc, pdf, 0.0), N,
                    cos_edges=np.linspace(1.0 - omc, 1.0, 21), what=f"uniform_cone({omc})")


@pytest.mark.parametrize("omc", [1e-6, 1e-12])
def test_uniform_cone_tiny(rng, chi2_counts, omc):
    # A light far away subtends a cone whose cos θmax rounds to 1; the warp takes 1 − cos θmax so
    # that it stays exact. 1 − cos θ is recovered without cancellation as sin²θ/(1 + cos θ).
    w = _warp_many(CONE, rng.random((N, 2)), omc)
    sin2 = w[:, 0] ** 2 + w[:, 1] ** 2
    x = sin2 / (1.0 + w[:, 2]) / omc  # (1 − cos θ)/omc: uniform on [0, 1] for a uniform cone
    assert np.all(np.abs(sin2 + w[:, 2] ** 2 - 1.0) < 1e-15)  # unit, to a few ulps
    assert x.min() >= 0.0 and x.max() <= 1.0 + 1e-9
    # Resolution: a cone computed from cos θmax = 1 − omc (or sin θ from 1 − cos²θ) can only
    # produce the few thousand angles that cos θ has floats for near 1 (steps of 1.1e-16, i.e.
    # 1.1e-4 of omc = 1e-12); the exact warp gives every sample its own angle.
    assert np.unique(x).size > 0.99 * N
    assert uniform_cone_pdf(omc) == pytest.approx(1.0 / (2.0 * math.pi * omc), rel=1e-15)
    counts, _ = np.histogram(x, bins=100, range=(0.0, 1.0))
    chi2_counts(counts, np.full(100, N / 100), f"(1 - cos θ)/omc of uniform_cone({omc})")
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2.0 * np.pi)
    counts, _ = np.histogram(phi, bins=100, range=(0.0, 2.0 * np.pi))
    chi2_counts(counts, np.full(100, N / 100), f"φ of uniform_cone({omc})")


@pytest.mark.parametrize("exponent", [1.0, 10.0, 200.0])
def test_phong_lobe_chi2(rng, chi2_directions, exponent):
    # Against the closed form (n + 1)/(2π) cosⁿα, and the renderer's phong_lobe_pdf agrees with it.
    def pdf(w):
        return (exponent + 1.0) / (2.0 * np.pi) * np.maximum(w[:, 2], 0.0) ** exponent

    chi2_directions(lambda n: _warp_many(PHONG_LOBE, rng.random((n, 2)), exponent), pdf, N,
                    cos_edges=lobe_edges(exponent), what=f"phong_lobe({exponent})")
    w = _warp_many(SPHERE_WARP, rng.random((1000, 2)), 0.0)
    np.testing.assert_allclose(_warp_pdf_many(PHONG_LOBE, w, exponent), pdf(w), rtol=1e-12)


def test_warp_pdfs_match_closed_forms(rng):
    w = _warp_many(SPHERE_WARP, rng.random((1000, 2)), 0.0)
    np.testing.assert_allclose(_warp_pdf_many(COSINE, w, 0.0),
                               np.maximum(w[:, 2], 0.0) / np.pi, rtol=1e-14)
    np.testing.assert_allclose(_warp_pdf_many(CONE, w, 0.3),
                               np.where(w[:, 2] >= 0.7, 1.0 / (2.0 * np.pi * 0.3), 0.0),
                               rtol=1e-14)


def test_pdfs_integrate_to_one():
    # Gauss–Legendre in cos θ is exact for these polynomials in cos θ (degree ≤ 200 < 2·128), and
    # the densities do not depend on φ, so ∫ pdf dω = 2π Σ wᵢ pdf(cos θᵢ) up to rounding.
    x, wts = np.polynomial.legendre.leggauss(128)
    mu = 0.5 * (x + 1.0)  # nodes on [0, 1]
    up = np.stack([np.sqrt(1.0 - mu**2), np.zeros_like(mu), mu], axis=1)
    assert 2.0 * np.pi * 0.5 * np.sum(wts * _warp_pdf_many(COSINE, up, 0.0)) == pytest.approx(
        1.0, abs=1e-12)
    for exponent in (0.0, 1.0, 10.0, 200.0):
        total = 2.0 * np.pi * 0.5 * np.sum(wts * _warp_pdf_many(PHONG_LOBE, up, exponent))
        assert total == pytest.approx(1.0, abs=1e-12), exponent


def test_uniform_triangle(rng, chi2_counts):
    b = _triangle_many(rng.random((N, 2)))
    b1, b2 = b[:, 0], b[:, 1]
    assert b.min() >= 0.0 and (b1 + b2).max() <= 1.0 + 1e-15

    # Moments of the uniform distribution on the triangle b1, b2 ≥ 0, b1 + b2 ≤ 1:
    # E[bᵢ] = 1/3, Var[bᵢ] = 1/18, Cov[b1, b2] = −1/36. Tolerance 5σ of each estimator (their
    # standard deviations: bᵢ is Beta(1, 2), whose central 4th moment is μ4 = 1/135, so the sample
    # variance has sd √(μ4 − σ⁴)/√N; for the covariance, Var[(b1 − ⅓)(b2 − ⅓)] ≤ μ4 by
    # Cauchy–Schwarz).
    s = 1.0 / math.sqrt(N)
    assert abs(b1.mean() - 1 / 3) < 5 * math.sqrt(1 / 18) * s
    assert abs(b2.mean() - 1 / 3) < 5 * math.sqrt(1 / 18) * s
    sd_var = math.sqrt(1 / 135 - 1 / 18**2)
    assert abs(b1.var() - 1 / 18) < 5 * sd_var * s
    assert abs(b2.var() - 1 / 18) < 5 * sd_var * s
    assert abs(np.cov(b1, b2)[0, 1] + 1 / 36) < 5 * math.sqrt(1 / 135) * s

    # Chi² on k² equal-area cells: the triangle cut by the lines b1 = i/k, b2 = j/k and
    # b1 + b2 = m/k; cell (i, j) holds a lower triangle, and an upper one when i + j ≤ k − 2.
    k = 20
    i = np.minimum((b1 * k).astype(int), k - 1)
    j = np.minimum((b2 * k).astype(int), k - 1)
    upper = (b1 * k - i) + (b2 * k - j) >= 1.0
    cell = 2 * (i * k + j) + upper
    counts = np.bincount(cell, minlength=2 * k * k).astype(float)
    ii, jj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    exists = np.stack([ii + jj <= k - 1, ii + jj <= k - 2], axis=-1).ravel()
    assert counts[~exists].sum() == 0  # nothing outside the triangle
    assert exists.sum() == k * k
    chi2_counts(counts[exists], np.full(k * k, N / (k * k)), "uniform_triangle")


def test_sample_discrete(rng, chi2_counts):
    weights = np.array([1.0, 0.0, 2.5, 0.5, 4.0, 0.0, 2.0, 0.02])
    cdf = np.cumsum(weights)  # inclusive running sum, not normalized
    idx = _discrete_many(cdf, rng.random(N))
    counts = np.bincount(idx, minlength=len(weights))
    assert len(counts) == len(weights)
    chi2_counts(counts, N * weights / weights.sum(), "sample_discrete")  # zero weights: never
    # The ends of [0, 1) pick the first and the last entries of non-zero weight.
    assert sample_discrete(cdf, 0.0) == 0
    assert sample_discrete(cdf, np.nextafter(1.0, 0.0)) == 7
    assert sample_discrete(np.cumsum([0.0, 0.0, 1.0, 0.0]), 0.0) == 2
    assert sample_discrete(np.cumsum([0.0, 0.0, 1.0, 0.0]), np.nextafter(1.0, 0.0)) == 2


# --- BSDF sampling --------------------------------------------------------------------------------

NORMAL = vec(unit([0.3, -0.5, 0.8]))  # not an axis, so the frames of to_world are exercised

KD, KS = [0.4, 0.3, 0.2], [0.3, 0.4, 0.5]  # a Phong surface with kd + ks < 1 in every channel
BSDF_CASES = [
    pytest.param(DIFFUSE, phong_param([0.8, 0.5, 0.2], [0, 0, 0], 0), 0.0, id="diffuse-normal"),
    pytest.param(DIFFUSE, phong_param([0.8, 0.5, 0.2], [0, 0, 0], 0), 70.0, id="diffuse-70deg"),
    pytest.param(PHONG, phong_param(KD, KS, 10), 0.0, id="phong10-normal"),
    pytest.param(PHONG, phong_param(KD, KS, 200), 0.0, id="phong200-normal"),
    pytest.param(PHONG, phong_param(KD, KS, 10), 50.0, id="phong10-50deg"),
    pytest.param(PHONG, phong_param([0.1, 0.1, 0.1], [0.6, 0.7, 0.8], 40), 75.0,
                 id="phong40-75deg"),
    pytest.param(PHONG, phong_param([0.0, 0.0, 0.0], [0.5, 0.5, 0.5], 1), 80.0, id="phong1-80deg"),
]


@pytest.mark.parametrize("kind,param,theta_o", BSDF_CASES)
def test_bsdf_sample_chi2(rng, chi2_directions, kind, param, theta_o):
    # Directions are binned about the normal, so the horizon is a cell edge; at normal incidence
    # the cells are refined where the specular lobe lies. Samples the sampler refuses (the lobe
    # below the horizon) must be exactly the mass bsdf_pdf lacks over the hemisphere.
    wo = oblique(NORMAL, theta_o)
    edges = np.linspace(0.0, 1.0, 21)
    if kind == PHONG and theta_o == 0.0:
        edges = np.union1d(edges, lobe_edges(param[6], 10))
        edges = edges[edges >= 0.0]
    wi, weight, pdf, ok = _bsdf_sample_many(kind, param, wo, NORMAL, rng.random((N, 3)))
    assert ok.mean() > 0.5
    chi2_directions(lambda n: wi, lambda w: _bsdf_eval_pdf_many(kind, param, wo, NORMAL, w)[1], N,
                    axis=NORMAL, cos_edges=edges, n_phi=32, what=f"bsdf_sample({kind})")

    # The weight is f·cos θi/pdf, and the returned pdf is bsdf_pdf, for the same wi.
    f, pdf_eval = _bsdf_eval_pdf_many(kind, param, wo, NORMAL, wi[ok][:20000])
    np.testing.assert_allclose(pdf[ok][:20000], pdf_eval, rtol=1e-12)
    np.testing.assert_allclose(weight[ok][:20000], f / pdf_eval[:, None], rtol=1e-12)
    if kind == DIFFUSE:
        np.testing.assert_allclose(weight[ok], np.broadcast_to(param[0:3], weight[ok].shape),
                                   rtol=1e-15)


@pytest.mark.parametrize("theta_o", [0.0, 45.0, 80.0])
def test_phong_pdf_integral(rng, theta_o):
    # ∫ phong_pdf dω over the hemisphere is 1 at normal incidence; at oblique incidence the part of
    # the specular lobe below the horizon is lost, and ∫ pdf = P(ok) of phong_sample. Quadrature
    # about the normal: Gauss–Legendre (256 nodes) in cos θ, where the horizon is an end point and
    # the integrand is otherwise smooth (the lobe meets its cut-off as cos²⁰α), and the midpoint
    # rule (512 nodes) in φ, spectrally accurate for a periodic integrand: error < 1e-9. P(ok) is
    # estimated from N samples, hence the ±5σ binomial tolerance.
    param = phong_param([0.2, 0.2, 0.2], [0.6, 0.6, 0.6], 20)
    wo = oblique(NORMAL, theta_o)
    x, wts = np.polynomial.legendre.leggauss(256)
    c = 0.5 * (x + 1.0)
    phi = (np.arange(512) + 0.5) / 512 * 2.0 * np.pi
    cc, pp = np.meshgrid(c, phi, indexing="ij")
    s = np.sqrt(1.0 - cc**2)
    t = unit(np.cross(NORMAL, [1.0, 0.0, 0.0]))
    basis = np.stack([t, np.cross(NORMAL, t), NORMAL])  # rows t, b, n
    w = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3) @ basis
    pdf = _bsdf_eval_pdf_many(PHONG, param, wo, NORMAL, w)[1].reshape(cc.shape)
    total = 0.5 * np.sum(wts[:, None] * pdf) * (2.0 * np.pi / 512)
    if theta_o == 0.0:
        assert total == pytest.approx(1.0, abs=1e-9)
    _, _, _, ok = _bsdf_sample_many(PHONG, param, wo, NORMAL, rng.random((N, 3)))
    p_ok = ok.mean()
    assert abs(total - p_ok) < 5.0 * math.sqrt(max(p_ok * (1 - p_ok), 1e-6) / N)
    assert total <= 1.0 + 1e-9


# --- light sampling -------------------------------------------------------------------------------

P_SHADE = vec([0.1, 0.2, 0.0])  # the shading point
SPHERE_GEO = [0.4, -0.3, 3.0, 1.0, 0, 0, 0, 0, 0]  # centre (0.4, −0.3, 3), radius 1
# Edges chosen so that cross(e1, e2) points down, towards the shading point (the emitting side).
QUAD_GEO = [-0.5, -0.3, 2.0, 0.2, 0.9, 0.3, 1.2, 0.1, 0.0]
TRI_GEO = [-0.6, -0.4, 1.5, 0.3, 1.4, 0.6, 1.5, -0.2, 0.1]


def light_table(kind, geo):
    """A point light (pmf 0.3) and the area light under test (pmf 0.7), primitive index 1."""
    prim_kind = np.array([SPHERE, kind], np.int8)
    prim_geo = np.array([[9.0, 9.0, 9.0, 0.5, 0, 0, 0, 0, 0], geo], np.float64)
    light_kind = np.array([POINT, AREA], np.int32)
    light_prim = np.array([-1, 1], np.int64)
    light_data = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 2.0, 3.0, 4.0]])
    light_pmf = np.array([0.3, 0.7])
    return (light_kind, light_prim, light_data, np.cumsum(light_pmf), light_pmf, prim_kind,
            prim_geo)


def cone_cos_min(kind, geo, p) -> tuple[np.ndarray, float]:
    """The axis from p to the light and the cosine of the widest angle of the light from it."""
    p = np.asarray(p)
    g = np.asarray(geo, dtype=np.float64)
    if kind == SPHERE:
        d = np.linalg.norm(g[0:3] - p)
        return unit(g[0:3] - p), math.sqrt(1.0 - (g[3] / d) ** 2)
    corners = [g[0:3], g[0:3] + g[3:6], g[0:3] + g[6:9]]
    if kind == QUAD:
        corners.append(g[0:3] + g[3:6] + g[6:9])
    axis = unit(np.mean(corners, axis=0) - p)
    # A convex polygon lies inside the cone about axis through its widest vertex.
    return axis, min(float(unit(c - p) @ axis) for c in corners)


@pytest.mark.parametrize("kind,geo", [(QUAD, QUAD_GEO), (TRIANGLE, TRI_GEO), (SPHERE, SPHERE_GEO)],
                         ids=["quad", "triangle", "sphere"])
def test_area_light_sample_chi2(rng, chi2_directions, kind, geo):
    table = light_table(kind, geo)
    light_pmf, prim_geo = table[4], table[6]
    wi, li, pdf, t_max, delta = _light_sample_many(*table, P_SHADE, rng.random((N, 3)))
    area = ~delta
    assert np.all(pdf[area] > 0.0)
    np.testing.assert_array_equal(li[area], np.broadcast_to([2.0, 3.0, 4.0], li[area].shape))

    # The point light is chosen with its pmf; its samples are the rest cell of the chi² test, so
    # the area light's density must integrate to its own pmf 0.7.
    axis, cos_min = cone_cos_min(kind, geo, P_SHADE)
    edges = np.linspace(cos_min - 1e-9, 1.0, 21)
    chi2_directions(lambda n: np.where(area[:, None], wi, np.nan),
                    lambda w: _area_light_pdf_many(light_pmf, 1, kind, prim_geo[1], P_SHADE, w),
                    N, axis=axis, cos_edges=edges, n_phi=40, sub=24, what=f"sample_light({kind})")

    # The point each sample aims at is on the light (t_max along wi), on its near side, and the
    # returned pdf is area_light_pdf of that point.
    q = np.asarray(P_SHADE) + t_max[area][:, None] * wi[area]
    g = np.asarray(geo)
    if kind == SPHERE:
        np.testing.assert_allclose(np.linalg.norm(q - g[0:3], axis=1), g[3], rtol=1e-12)
        assert np.all(np.einsum("ij,ij->i", wi[area], q - g[0:3]) < 0.0)
    else:
        nrm = unit(np.cross(g[3:6], g[6:9]))
        st = np.linalg.lstsq(np.stack([g[3:6], g[6:9]], axis=1), (q - g[0:3]).T, rcond=None)[0]
        np.testing.assert_allclose((q - g[0:3]) @ nrm, 0.0, atol=1e-12)
        assert st.min() > -1e-12 and (st.sum(axis=0) if kind == TRIANGLE else st).max() < 1 + 1e-12
        assert np.all(wi[area] @ nrm < 0.0)  # arriving on the emitting side
    pdf_at = _area_light_pdf_at(light_pmf, 1, kind, prim_geo[1], P_SHADE, wi[area], t_max[area])
    np.testing.assert_allclose(pdf[area], pdf_at, rtol=1e-9)


def test_area_light_back_side_gives_nothing(rng):
    # The shading point behind a quad light (above it, against its normal): no sample contributes.
    table = light_table(QUAD, QUAD_GEO)
    wi, li, pdf, t_max, delta = _light_sample_many(*table, (0.1, 0.2, 4.0), rng.random((2000, 3)))
    assert np.all(pdf[~delta] == 0.0) and np.all(li[~delta] == 0.0)
    assert 0 < (~delta).sum() < 2000


def test_background_light_chi2(rng, chi2_directions):
    # Background (pmf 0.6) and a point light (pmf 0.4): uniform directions with pdf 0.6/(4π).
    light_kind = np.array([POINT, BACKGROUND], np.int32)
    light_prim = np.array([-1, -1], np.int64)
    light_data = np.array([[0.0, 0.0, 5.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.5, 0.6, 0.7]])
    light_pmf = np.array([0.4, 0.6])
    prim_kind = np.zeros(1, np.int8)
    prim_geo = np.zeros((1, 9))
    wi, li, pdf, t_max, delta = _light_sample_many(light_kind, light_prim, light_data,
                                                   np.cumsum(light_pmf), light_pmf, prim_kind,
                                                   prim_geo, P_SHADE, rng.random((N, 3)))
    bg = ~delta
    np.testing.assert_allclose(pdf[bg], 0.6 / (4.0 * np.pi), rtol=1e-15)
    assert np.all(np.isinf(t_max[bg]))
    np.testing.assert_array_equal(li[bg], np.broadcast_to([0.5, 0.6, 0.7], li[bg].shape))
    chi2_directions(lambda n: np.where(bg[:, None], wi, np.nan),
                    lambda w: np.full(len(w), 0.6 / (4.0 * np.pi)), N, what="background light")
