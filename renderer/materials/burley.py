"""Christensen–Burley normalized diffusion: the radial reflectance profile, its CDF and sampling.

Christensen & Burley, "Approximate Reflectance Profiles for Efficient Subsurface Scattering",
Pixar Technical Memo 15-04 (2015). Light entering a thick, flat slab at a point leaves it at
distance r with the radial profile A·R(r), where (eqs. 2–3)

    R(r) = (e^{−r/d} + e^{−r/(3d)}) / (8π d r),        ∫₀^∞ R(r) 2πr dr = 1,

A is the surface albedo (the total diffuse reflectance, applied by the caller) and d = ℓ/s is the
profile's width: ℓ the mean free path, s a shape factor fitted to Monte Carlo references (eq. 5,
``burley_s``). Everything here works on one channel at a time, on scalars.

In polar coordinates the radius has the density p(r) = 2πr R(r) = (e^{−r/d} + e^{−r/(3d)})/(4d),
a ¼ : ¾ mixture of exponentials of means d and 3d, so E[r] = d/4 + 9d/4 = 5d/2; its CDF is (eq. 11)

    P(r) = 1 − e^{−r/d}/4 − 3 e^{−r/(3d)}/4.

The paper samples r by Newton iteration on P (as Cycles does, ``bssrdf_burley_root_find`` in
``intern/cycles/kernel/closure/bssrdf.h``), but P inverts in closed form (MoonRay's
``inverseDiffusionCDF``, lib/rendering/shading/bssrdf/NormalizedDiffusion.cc; Zero Radiance,
"Sampling Burley's Normalized Diffusion Profiles"): with x = e^{−r/(3d)}, P(r) = u reads
x³ + 3x = 4(1 − u), a depressed cubic with positive linear term and so one real root,
x = 2 sinh(asinh(2(1 − u))/3) (Cardano's formula in hyperbolic form), and r = −3d ln x.
``burley_sample_radius`` evaluates it so that r keeps full relative precision at both ends.

Unlike Cycles (which truncates the profile at 16d and renormalizes), nothing here is truncated:
the profile, pdf and CDF are exact, and ``burley_r_max`` gives the radius that holds a chosen
share of the energy, for the length of probe rays.
"""

from __future__ import annotations

import math

from renderer.jit import kernel

INV_8PI = 1.0 / (8.0 * math.pi)
SQRT5 = math.sqrt(5.0)
# asinh(1/2) = ln φ (φ the golden ratio): the root x = 2 sinh(t0) = 1 of the cubic at u = 0.
T0 = math.asinh(0.5)


@kernel
def burley_s(albedo):
    """Shape factor s(A) for the searchlight configuration, mfp parameterization (eq. 5).

    ``albedo`` is the surface albedo A in [0, 1]. The paper fits two other configurations: diffuse
    surface transmission, s = 1.9 − A + 3.5(A − 0.8)² (eq. 6, Cycles' ``bssrdf_burley_fitting``),
    and the searchlight with the diffuse mean free path as parameter, s = 3.5 + 100(A − 0.33)⁴
    (eq. 8, MoonRay's choice). Lucent's width parameter is the volume's mean free path, so eq. 5.
    """
    x = abs(albedo - 0.8)
    return 1.85 - albedo + 7.0 * x * x * x


@kernel
def burley_d(albedo, mfp):
    """Profile width d = ℓ/s(A), with ``mfp`` ℓ = 1/σt (Lucent's ``density`` is σt)."""
    return mfp / burley_s(albedo)


@kernel
def burley_profile(r, d):
    """R(r) = (e^{−r/d} + e^{−r/(3d)}) / (8π d r), normalized over the plane (eqs. 2–3, A = 1).

    +inf at r = 0, where the profile has an integrable 1/r singularity.
    """
    e3 = math.exp(-r / (3.0 * d))  # e^{−r/(3d)}; its cube is e^{−r/d}
    return (e3 * e3 * e3 + e3) * INV_8PI / (d * r)


@kernel
def burley_cdf(r, d):
    """P(r) = 1 − e^{−r/d}/4 − 3e^{−r/(3d)}/4 (eq. 11): the share of the energy within radius r.

    Written with expm1 so that P keeps its relative precision for r ≪ d (P ≈ r/(2d)).
    """
    if r <= 0.0:
        return 0.0
    return -0.25 * (math.expm1(-r / d) + 3.0 * math.expm1(-r / (3.0 * d)))


@kernel
def burley_pdf_radius(r, d):
    """Density of the radius, p(r) = 2πr R(r) = (e^{−r/d} + e^{−r/(3d)}) / (4d), for r ≥ 0."""
    if r < 0.0:
        return 0.0
    e3 = math.exp(-r / (3.0 * d))
    return 0.25 * (e3 * e3 * e3 + e3) / d


@kernel
def burley_pdf_area(r, d):
    """Density per unit area on the tangent plane of a point at distance r sampled by
    ``burley_sample_radius`` and a uniform angle: p(r)/(2πr) = R(r) (+inf at r = 0)."""
    return burley_profile(r, d)


@kernel
def burley_sample_radius(u, d):
    """The radius r with P(r) = u, by the exact inversion of the CDF; u in [0, 1).

    r = −3d ln x with x = 2 sinh(asinh(2(1 − u))/3), the real root of x³ + 3x = 4(1 − u). Two
    forms keep r's relative precision (a few ulps) across the whole range:
    - u ≥ 1/2: x as written; 1 − u is exact there (Sterbenz) and x ≈ 4(1 − u)/3 as u → 1 never
      underflows, so u = 1 − 2⁻⁵³ (the largest double below 1) gives r ≈ 109d, not inf;
    - u < 1/2: x is close to 1 and ln x would lose r ≈ 2du to cancellation, so x − 1 is computed
      directly, as 2 sinh(t0 + Δ/3) − 2 sinh(t0) = 4 cosh(t0 + Δ/6) sinh(Δ/6), with t0 = asinh(½)
      and Δ = asinh(2(1 − u)) − asinh(2) = asinh(−2u(2 − u) / ((1 − u)√5 + √(1 + 4(1 − u)²)))
      (from sinh(α − β) = sinh α cosh β − cosh α sinh β, rationalized), then r = −3d log1p(x − 1).
    u = 0 gives r = 0 and u = 1 gives +inf.
    """
    if u >= 0.5:
        w = 1.0 - u
        x = 2.0 * math.sinh(math.asinh(2.0 * w) / 3.0)
        return -3.0 * d * math.log(x)
    w = 1.0 - u
    q = -2.0 * u * (2.0 - u) / (w * SQRT5 + math.sqrt(1.0 + 4.0 * w * w))
    delta6 = math.asinh(q) / 6.0
    x_minus_1 = 4.0 * math.cosh(T0 + delta6) * math.sinh(delta6)
    return -3.0 * d * math.log1p(x_minus_1) + 0.0  # + 0.0: r = +0, not −0, at u = 0


@kernel
def burley_r_max(d, quantile=0.999):
    """Radius holding ``quantile`` of the profile's energy, P(r_max) = quantile: the reach of
    probe rays, beyond which the profile is neglected. The e^{−r/(3d)} tail is long: r_max is
    19.9d at 0.999 (Cycles truncates at 16d, P = 0.9964)."""
    return burley_sample_radius(quantile, d)


@kernel
def burley_sample_point(u1, u2, d):
    """Offset (x, y) on the tangent plane with density ``burley_pdf_area``, and its radius."""
    r = burley_sample_radius(u1, d)
    phi = 2.0 * math.pi * u2
    return r * math.cos(phi), r * math.sin(phi), r
