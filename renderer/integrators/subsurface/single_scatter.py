"""The seed paper's single_scatter method: a surface share, and at most one event inside.

After Lundgren's "A Simple Approach To Translucent Materials" (the seed paper): a hit on the
surface reflects as a Lambertian surface with probability ``surface_fraction`` (its BSDF,
``renderer.materials.bsdf``); the rest of the light goes in straight on (the paper does not
refract), scatters at most once inside (the free flight and event of
``renderer/integrators/subsurface/volumetric.py``), and leaves straight too. Shadow rays see the
same surface (``renderer.integrators.shadow.transmittance``), so MIS stays consistent. Slots:
``renderer/materials/translucent.py``; the method: docs/methods/single_scatter.md.
"""

from __future__ import annotations

import math

from renderer.integrators.sampler import draw
from renderer.jit import block
from renderer.materials.translucent import SIGMA_T, SURFACE_FRACTION


@block
def passes_straight(S, mp, cos_o, key, dim, sidx, sob):
    """Whether a hit on the surface (row ``mp``; cos_o < 0 from inside) goes straight through:
    always on the way out, with probability 1 − surface_fraction on the way in."""
    return cos_o < 0.0 or draw(S, key, dim, 3, sidx, sob) >= mp[SURFACE_FRACTION]


@block
def after_the_event(S, medium, t, br, bg, bb):
    """β over a segment of length t inside ``medium`` after its one scattering event: light only
    attenuates on its way out, by exp(−σt·t), σt per channel."""
    return (br * math.exp(-S.mat_param[medium, SIGMA_T] * t),
            bg * math.exp(-S.mat_param[medium, SIGMA_T + 1] * t),
            bb * math.exp(-S.mat_param[medium, SIGMA_T + 2] * t))
