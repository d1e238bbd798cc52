"""Measured media (``preset``) and the other forms of a translucent material's coefficients."""

from __future__ import annotations

import pytest

from renderer.materials.presets import PRESETS, preset_coefficients
from renderer.scene.schema import TranslucentMaterial

# Jensen, Marschner, Levoy, Hanrahan, "A Practical Model for Subsurface Light Transport",
# SIGGRAPH 2001, Table 1: σs′ [mm⁻¹] R, G, B, then σa [mm⁻¹] R, G, B — typed from the paper.
PAPER = """
apple      2.29 2.39 1.97   0.0030 0.0034 0.046
chicken1   0.15 0.21 0.38   0.015  0.077  0.19
chicken2   0.19 0.25 0.32   0.018  0.088  0.20
cream      7.38 5.47 3.15   0.0002 0.0028 0.0163
ketchup    0.18 0.07 0.03   0.061  0.97   1.45
marble     2.19 2.62 3.00   0.0021 0.0041 0.0071
potato     0.68 0.70 0.55   0.0024 0.0090 0.12
skimmilk   0.70 1.22 1.90   0.0014 0.0025 0.0142
skin1      0.74 0.88 1.01   0.032  0.17   0.48
skin2      1.09 1.59 1.79   0.013  0.070  0.145
wholemilk  2.55 3.21 3.77   0.0011 0.0024 0.014
"""


def test_the_preset_table_is_the_papers():
    rows = {line.split()[0]: [float(x) for x in line.split()[1:]]
            for line in PAPER.strip().splitlines()}
    assert set(PRESETS) == set(rows)
    for name, values in rows.items():
        sigma_s_prime, sigma_a = PRESETS[name]
        assert list(sigma_s_prime) + list(sigma_a) == values, name


def test_a_preset_becomes_coefficients_per_scene_unit():
    """σs = σs′/(1 − g), both scaled by millimetres per scene unit; albedo = σs/σt."""
    m = TranslucentMaterial(preset="skin1", preset_scale=10.0, g=0.5)
    s, a = preset_coefficients("skin1", 0.5, 10.0)
    assert s == pytest.approx((14.8, 17.6, 20.2)) and a == pytest.approx((0.32, 1.7, 4.8))
    assert m.sigma_t == pytest.approx((15.12, 19.3, 25.0))
    assert m.albedo_rgb == pytest.approx((14.8 / 15.12, 17.6 / 19.3, 20.2 / 25.0))
    assert m.chromatic


def test_sigma_s_and_sigma_a_give_albedo_and_density():
    m = TranslucentMaterial(sigma_s=(1.0, 2.0, 0.0), sigma_a=(1.0, 0.0, 4.0))
    assert m.sigma_t == (2.0, 2.0, 4.0) and m.albedo_rgb == (0.5, 1.0, 0.0)


def test_grey_and_rgb_density():
    assert TranslucentMaterial(density=3.0).sigma_t == (3.0, 3.0, 3.0)
    assert not TranslucentMaterial(density=3.0).chromatic
    assert TranslucentMaterial(density=(3.0, 3.0, 3.0)).chromatic is False
    assert TranslucentMaterial(density=(1.0, 2.0, 3.0)).chromatic


def test_a_material_round_trips_through_its_dump():
    """A loaded material dumped and loaded again (the CLI's and the farm's path) is the same."""
    for m in (TranslucentMaterial(preset="marble", preset_scale=10.0),
              TranslucentMaterial(sigma_s=(1.0, 2.0, 3.0), sigma_a=(0.1, 0.1, 0.1)),
              TranslucentMaterial(density=(1.0, 2.0, 3.0), albedo=(0.9, 0.8, 0.7))):
        again = TranslucentMaterial.model_validate(m.model_dump())
        assert (again.albedo_rgb, again.sigma_t) == (m.albedo_rgb, m.sigma_t)
