"""The ``translucent`` material's row: the parameters every method shares, then each method's.

A translucent object is a homogeneous medium behind a dielectric boundary (its ``IOR`` slot is
the dielectric's, so a smooth boundary samples as ``dielectric_sample``; a rough one, method
volumetric only, as ``rough_boundary_sample``). The shared slots are the material's own
parameters; from slot 7 on, each method keeps its knobs and what the compiler derives for it, so
slot 7 names four things by method — each under its own name here. The ``diffusion`` method's
slots are in ``renderer/materials/diffusion.py``.

======================  =====  =========================================================
Slot                    Index  Meaning
======================  =====  =========================================================
``IOR``                 0      index of refraction of the boundary (1: index-matched)
``ALBEDO``              1–3    single-scattering albedo σs/σt (RGB)
``DENSITY``             4      extinction σt (per unit length) of a grey medium
``G``                   5      Henyey–Greenstein asymmetry
``CHROMATIC``           6      1 when σt differs between channels (the walk samples by channel)
``SIGMA_T``             20–22  extinction σt per channel (all three equal DENSITY when grey)
``BOUNDARY_ROUGHNESS``  19     GGX α of the boundary (volumetric; 0: smooth, kind TRANSLUCENT)
``SURFACE_FRACTION``    7      single_scatter: the share of hits that reflect at the surface
``DIRECT_LIGHT``        7      diffuse_entry: 1 when the entry point is lit apart
``SPECULAR_EXP``        8      diffuse_entry: the glossy coat's Phong exponent (0: none)
``DISTORTION``          7      backlight: how far the normal bends the transmitted lobe
``POWER``               8      backlight: the lobe's exponent
``SCALE``               9      backlight: the transmitted share
``REFLECTED``           12–14  backlight: (1 − scale)·albedo, what the surface reflects
``SIGMA_EFF``           16–18  backlight: σ_eff per channel, the decay with thickness
======================  =====  =========================================================
"""

from __future__ import annotations

import numpy as np

from renderer.materials.dielectric import IOR

__all__ = ["IOR", "ALBEDO", "DENSITY", "G", "CHROMATIC", "SIGMA_T", "BOUNDARY_ROUGHNESS",
           "SURFACE_FRACTION", "DIRECT_LIGHT", "SPECULAR_EXP", "DISTORTION", "POWER", "SCALE",
           "REFLECTED", "SIGMA_EFF"]

ALBEDO = 1
DENSITY = 4
G = 5
CHROMATIC = 6
SIGMA_T = 20
BOUNDARY_ROUGHNESS = 19
SURFACE_FRACTION = 7
DIRECT_LIGHT = 7
SPECULAR_EXP = 8
DISTORTION = 7
POWER = 8
SCALE = 9
REFLECTED = 12
SIGMA_EFF = 16


def pack_translucent(p, m) -> None:
    """Write the slots every method shares (and that ``volumetric`` needs alone) into ``p``:
    the coefficients in whichever form the material gives them (``albedo_rgb``, ``sigma_t``)."""
    p[IOR] = m.ior
    p[ALBEDO:ALBEDO + 3] = m.albedo_rgb
    p[SIGMA_T:SIGMA_T + 3] = m.sigma_t
    p[DENSITY] = max(m.sigma_t)  # the grey σt; a chromatic walk reads SIGMA_T
    p[CHROMATIC] = 1.0 if m.chromatic else 0.0
    p[G] = m.g
    p[BOUNDARY_ROUGHNESS] = m.roughness


def pack_single_scatter(p, m) -> None:
    """The seed paper's method (Hanrahan–Krueger-style single scattering): its surface share."""
    pack_translucent(p, m)
    p[SURFACE_FRACTION] = 0.8 if m.surface_fraction is None else m.surface_fraction


def pack_diffuse_entry(p, m) -> None:
    """The seed student project's method: its separate direct light and glossy coat."""
    pack_translucent(p, m)
    p[DIRECT_LIGHT] = 1.0 if m.direct_light else 0.0
    p[SPECULAR_EXP] = 0.0 if m.specular_exponent is None else m.specular_exponent


def pack_backlight(p, m) -> None:
    """The seed lecture's backlight approximation: its lobe, share and decay rates."""
    pack_translucent(p, m)
    p[DISTORTION] = 0.2 if m.distortion is None else m.distortion
    p[POWER] = 4.0 if m.power is None else m.power
    p[SCALE] = min(1.0, 0.5 if m.scale is None else m.scale)  # the transmitted share
    p[REFLECTED:REFLECTED + 3] = (1.0 - p[SCALE]) * np.asarray(m.albedo_rgb)
    # Diffuse light decays through a slab as e^{−σ_eff·d}, σ_eff = √(3σa(σa + σs')) with
    # σs' = σs(1 − g) (diffusion theory, e.g. Jensen et al. 2001): not e^{−σt·d}, which is the
    # unscattered part only and would make any dense material black from behind.
    # Each channel at its own σt (a chromatic medium's red decays slower than its blue)
    albedo = np.asarray(m.albedo_rgb)
    sigma_t = np.asarray(m.sigma_t)
    sigma_a = sigma_t * (1.0 - albedo)
    sigma_s_reduced = sigma_t * albedo * (1.0 - m.g)
    p[SIGMA_EFF:SIGMA_EFF + 3] = np.sqrt(3.0 * sigma_a * (sigma_a + sigma_s_reduced))
