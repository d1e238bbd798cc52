"""Smooth conductor (metal): mirror reflection weighted by the exact conductor Fresnel term.

A metal reflects a share F(θ) of the light that depends on its complex index of refraction
η + ik per channel: the unpolarized mean of the s- and p-polarized reflectances of the Fresnel
equations with a complex refractive index (Born & Wolf, Principles of Optics, §14.2; pbrt-v4's
FrComplex), times an optional ``specular`` scale. Row (``pack_conductor``): ``ETA`` and ``K``
(three slots each) and ``SPECULAR`` (three). ``preset`` names measured metals: their η and k at
650, 550 and 450 nm (``CONDUCTOR_PRESETS``).
"""

from __future__ import annotations

import cmath

from renderer.jit import kernel
from renderer.materials.fresnel import reflect

ETA = 0
K = 3
SPECULAR = 6

# η and k of measured metals at 650 nm (R), 550 nm (G) and 450 nm (B), from the data of
# refractiveindex.info (gold, silver, copper: Johnson & Christy 1972; aluminium: Rakić 1995) as
# tabulated in Chaos Group's "Understanding metalness" (the same RGB table Hindefjord gives)
CONDUCTOR_PRESETS = {
    "Au": ((0.18299, 0.42108, 1.3734), (3.4242, 2.3459, 1.7704)),
    "Ag": ((0.15943, 0.14512, 0.13547), (3.9291, 3.1900, 2.3808)),
    "Cu": ((0.27105, 0.67693, 1.3164), (3.6092, 2.6248, 2.2921)),
    "Al": ((1.3456, 0.96521, 0.61722), (7.4746, 6.3995, 5.3031)),
}


def pack_conductor(p, m) -> None:
    """Write a ``conductor`` material's row into ``p``."""
    eta, k = CONDUCTOR_PRESETS[m.preset] if m.preset is not None else (m.eta, m.k)
    p[ETA:ETA + 3] = eta
    p[K:K + 3] = k
    p[SPECULAR:SPECULAR + 3] = m.specular


@kernel
def fresnel_conductor(cos_i, eta, k):
    """Unpolarized reflectance of a smooth conductor of complex index η + ik, seen from a
    dielectric of index 1 at incidence cos θi ∈ [0, 1]."""
    cos_i = min(max(cos_i, 0.0), 1.0)
    n = complex(eta, k)
    sin2_t = (1.0 - cos_i * cos_i) / (n * n)
    cos_t = cmath.sqrt(1.0 - sin2_t)
    r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (abs(r_s) ** 2 + abs(r_p) ** 2)


@kernel
def conductor_sample(param, wo, n):
    """(wi, weight): the mirror direction, weighted by F(θ)·specular per channel (n faces wo)."""
    cos_o = wo[0] * n[0] + wo[1] * n[1] + wo[2] * n[2]
    return reflect(wo, n), (
        param[SPECULAR] * fresnel_conductor(cos_o, param[ETA], param[K]),
        param[SPECULAR + 1] * fresnel_conductor(cos_o, param[ETA + 1], param[K + 1]),
        param[SPECULAR + 2] * fresnel_conductor(cos_o, param[ETA + 2], param[K + 2]),
    )
