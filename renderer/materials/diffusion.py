"""The diffusion method: a separable BSSRDF with the Christensen–Burley profile.

S(p_o, w_o, p_i, w_i) = (1 − F(cos θ_o)) · S_p(|p_o − p_i|) · S_w(w_i) (pbrt-v3's
SeparableBSSRDF, §11.4 of Physically Based Rendering, 3rd ed.), with

- S_p(r) = A · R_burley(r; d) per channel: the normalized diffusion profile
  (``renderer.materials.burley``) scaled by the multiple-scattering albedo A;
- A from the material's single-scattering ``albedo`` through the reduced albedo α' = σs'/σt'
  (σs' = σs(1 − g)) and the dipole's total diffuse reflectance (Jensen et al., "A Practical Model
  for Subsurface Light Transport", SIGGRAPH 2001, eq. 5 with the boundary term A_F of its §2.4);
- d = ℓ / s(A), ℓ = 1/σt' the reduced mean free path, s the searchlight fit of Christensen & Burley
  (2015, eq. 5);
- S_w(w) = (1 − F(cos θ)) / (c π), c = 1 − 2 F̄₁(1/η) (the first Fresnel moment; pbrt-v3's
  polynomial fit) so S_w integrates to 1 against cos θ.

The exit point is found by probe rays along three axes (the normal with probability 1/2, each
tangent with 1/4; the radius from one of the three channels' profiles), and the exit is weighted
by the multiple-importance density over all 9 axis×channel strategies (King et al., "BSSRDF
Importance Sampling", 2013; as in pbrt-v3 and Cycles).

Row (``pack_diffusion``): the translucent slots (``renderer/materials/translucent.py``), then
``C_NORM`` c, ``OPAQUE`` (1: the zero-radius limit, renderer/materials/opaque.py), ``MS_ALBEDO``
A (three slots) and ``PROFILE_D`` d (three slots).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.jit import kernel
from renderer.materials.burley import burley_s
from renderer.materials.opaque import opaque_albedo
from renderer.materials.translucent import ALBEDO, IOR, SIGMA_T, G, pack_translucent

C_NORM = 7
OPAQUE = 10
MS_ALBEDO = 12
PROFILE_D = 16


def fresnel_moment1(eta: float) -> float:
    """First moment of the Fresnel reflectance, ∫₀¹ F(μ, η) μ dμ·2 (pbrt-v3's fit)."""
    e2, e3, e4, e5 = eta**2, eta**3, eta**4, eta**5
    if eta < 1:
        return (0.45966 - 1.73965 * eta + 3.37668 * e2 - 3.904945 * e3 + 2.49277 * e4
                - 0.68441 * e5)
    return -4.61686 + 11.1136 * eta - 10.4646 * e2 + 5.11455 * e3 - 1.27198 * e4 + 0.12746 * e5


def dipole_diffuse_reflectance(reduced_albedo: np.ndarray, eta: float) -> np.ndarray:
    """Total diffuse reflectance R_d of a semi-infinite medium (Jensen et al. 2001, eq. 5)."""
    f_dr = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    a_f = (1 + f_dr) / (1 - f_dr)
    root = np.sqrt(3 * (1 - reduced_albedo))
    return 0.5 * reduced_albedo * (1 + np.exp(-4 / 3 * a_f * root)) * np.exp(-root)


def diffusion_parameters(albedo, density, g: float, ior: float):
    """(A per channel, d per channel, c): what the kernels need, from the material's parameters
    (``density``: σt, one number or one per channel)."""
    albedo = np.asarray(albedo, dtype=np.float64)
    sigma_s_reduced = density * albedo * (1 - g)
    sigma_t_reduced = density * (1 - albedo) + sigma_s_reduced
    reduced_albedo = np.where(sigma_t_reduced > 0, sigma_s_reduced / np.maximum(
        sigma_t_reduced, 1e-300), 0.0)
    big_a = dipole_diffuse_reflectance(reduced_albedo, ior)
    mfp = 1.0 / np.maximum(sigma_t_reduced, 1e-300)
    d = np.array([mfp[i] / burley_s(float(big_a[i])) for i in range(3)])
    c = 1 - 2 * fresnel_moment1(1 / ior)
    return big_a, d, c



@kernel
def profile_from_albedo(p):
    """Rewrite the row ``p``'s A (``MS_ALBEDO``) and d (``PROFILE_D``) from its ``ALBEDO`` slots,
    as ``diffusion_parameters`` does on the host: for a textured albedo, looked up at a hit."""
    eta = p[IOR]
    f_dr = -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta
    a_f = (1.0 + f_dr) / (1.0 - f_dr)
    for c in range(3):
        sigma_s_reduced = p[SIGMA_T + c] * p[ALBEDO + c] * (1.0 - p[G])
        sigma_t_reduced = p[SIGMA_T + c] * (1.0 - p[ALBEDO + c]) + sigma_s_reduced
        reduced = sigma_s_reduced / sigma_t_reduced if sigma_t_reduced > 0.0 else 0.0
        root = math.sqrt(3.0 * (1.0 - reduced))
        big_a = 0.5 * reduced * (1.0 + math.exp(-4.0 / 3.0 * a_f * root)) * math.exp(-root)
        p[MS_ALBEDO + c] = big_a
        p[PROFILE_D + c] = 1.0 / max(sigma_t_reduced, 1e-300) / burley_s(big_a)


def pack_diffusion(p, m) -> None:
    """Write a ``diffusion`` material's row into ``p``."""
    pack_translucent(p, m)
    # Per channel: each channel's albedo and mean free path give its own A and profile radius d
    big_a, d, c = diffusion_parameters(m.albedo_rgb, np.asarray(m.sigma_t), m.g, m.ior)
    p[C_NORM] = c
    p[MS_ALBEDO:MS_ALBEDO + 3] = big_a
    p[PROFILE_D:PROFILE_D + 3] = d


def pack_opaque(p, m) -> None:
    """Switch the ``diffusion`` row ``p`` of an effectively opaque material to its zero-radius
    limit (renderer/materials/opaque.py): A is the semi-infinite medium's albedo from a walk, not
    the dipole's."""
    p[OPAQUE] = 1.0
    p[MS_ALBEDO:MS_ALBEDO + 3] = [opaque_albedo(a, m.g, m.ior) for a in m.albedo_rgb]
