"""Measured media for ``translucent``'s ``preset``: the table of Jensen et al. 2001.

Jensen, Marschner, Levoy and Hanrahan, "A Practical Model for Subsurface Light Transport",
SIGGRAPH 2001, Table 1 (measured at η = 1.3): the reduced scattering coefficient σs′ and the
absorption coefficient σa, in mm⁻¹, for the red, green and blue channels. (The same numbers are
pbrt-v3's and pbrt-v4's ``SubsurfaceParameterTable``.) A scene takes them with
``preset_scale`` = millimetres per scene unit (10 when a unit is a centimetre), and the
material's ``g``: σs = σs′/(1 − g) (σs′ = σs(1 − g) is what the measurement fixes; with g = 0,
σs = σs′).
"""

from __future__ import annotations

# name: (sigma_s_prime (mm^-1, RGB), sigma_a (mm^-1, RGB))
JENSEN_2001 = {
    "apple": ((2.29, 2.39, 1.97), (0.0030, 0.0034, 0.046)),
    "chicken1": ((0.15, 0.21, 0.38), (0.015, 0.077, 0.19)),
    "chicken2": ((0.19, 0.25, 0.32), (0.018, 0.088, 0.20)),
    "cream": ((7.38, 5.47, 3.15), (0.0002, 0.0028, 0.0163)),
    "ketchup": ((0.18, 0.07, 0.03), (0.061, 0.97, 1.45)),
    "marble": ((2.19, 2.62, 3.00), (0.0021, 0.0041, 0.0071)),
    "potato": ((0.68, 0.70, 0.55), (0.0024, 0.0090, 0.12)),
    "skimmilk": ((0.70, 1.22, 1.90), (0.0014, 0.0025, 0.0142)),
    "skin1": ((0.74, 0.88, 1.01), (0.032, 0.17, 0.48)),
    "skin2": ((1.09, 1.59, 1.79), (0.013, 0.070, 0.145)),
    "wholemilk": ((2.55, 3.21, 3.77), (0.0011, 0.0024, 0.014)),
}
PRESETS = JENSEN_2001


def preset_coefficients(name: str, g: float, scale: float) -> tuple[tuple[float, ...],
                                                                    tuple[float, ...]]:
    """(σs, σa) per scene unit, RGB, of preset ``name`` for phase asymmetry g, with ``scale``
    millimetres per scene unit."""
    sigma_s_prime, sigma_a = PRESETS[name]
    return (tuple(s / (1.0 - g) * scale for s in sigma_s_prime),
            tuple(a * scale for a in sigma_a))
