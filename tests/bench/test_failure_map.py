"""The coarse failure map: every translucent method in a white furnace (bench/failure_map.py).

A sphere alone under a white sky of radiance 1: with albedo ≤ 1 no pixel can exceed 1 in
expectation. Each method runs a 2×2×2×2 grid (albedo 0.5, 1 × optical size 0.5, 20 × g 0, 0.8 ×
ior 1, 1.5) at 8×8 pixels and 8 spp, and every cell must have

- no NaN/Inf samples (``SampleBuffer.dropped`` is 0);
- no energy gain beyond noise: the frame mean at most 1 + 6 standard errors, the standard error
  from ``SampleBuffer.variance_of_mean`` summed over the 64 independent pixels. 6 SE and not 3:
  80 cells are tested and the per-sample radiance is heavy-tailed, so the normal tail
  probability (~1e-9 per cell at 6 SE) is optimistic; a real gain of 1 % with the SE of these
  renders (~0.1–1 %) still shows at albedo 1, where the frame mean should be 1 exactly;
- every pixel finished all its samples (bounded work: a walk that never ended would hang here,
  which a CI timeout catches, rather than be timed).

Times per sample are measured and printed (``-s``), never asserted: the house rule is no
wall-clock assertion in a unit test.
"""

from __future__ import annotations

import pytest

from bench.failure_map import COARSE_GRID, METHODS, furnace_scene, measure, sphere_mask, sweep

SIZE, SPP = 8, 8


@pytest.fixture(scope="module")
def coarse_map() -> list[dict]:
    return sweep(COARSE_GRID, METHODS, size=SIZE, spp=SPP)


def _cell(row: dict) -> str:
    return (f"{row['method']} albedo {row['albedo']} optical size {row['optical_size']} "
            f"g {row['g']} ior {row['ior']}")


def test_the_sweep_covers_every_method_and_cell(coarse_map):
    assert len(coarse_map) == len(METHODS) * 16
    assert {r["method"] for r in coarse_map} == set(METHODS)


@pytest.mark.parametrize("method", METHODS)
def test_no_nan_or_inf(coarse_map, method):
    bad = [_cell(r) for r in coarse_map if r["method"] == method and r["dropped"] > 0]
    assert not bad, f"NaN/Inf samples in: {bad}"


@pytest.mark.parametrize("method", METHODS)
def test_no_energy_gain_beyond_noise(coarse_map, method):
    bad = [f"{_cell(r)}: mean {r['frame_mean']:.4f} ± {r['frame_se']:.4f}"
           for r in coarse_map if r["method"] == method and r["z_excess"] > 6.0]
    assert not bad, f"energy above the furnace bound of 1: {bad}"


@pytest.mark.parametrize("method", METHODS)
def test_every_pixel_finishes_its_samples(coarse_map, method):
    mine = [r for r in coarse_map if r["method"] == method]
    assert all(r["complete"] for r in mine)
    assert all(r["samples"] + r["dropped"] == SIZE * SIZE * SPP for r in mine)
    # recorded, not asserted (no wall-clock assertions in unit tests)
    worst = max(mine, key=lambda r: r["us_per_sample"])
    print(f"{method}: worst {worst['us_per_sample']:.1f} µs/sample at {_cell(worst)}")


def test_furnace_detects_an_energy_gain():
    """The check is not vacuous: a scene with an emitter inside the sky's bound fails it."""
    scene = furnace_scene("volumetric", 1.0, 0.5, 0.0, 1.0, SIZE, SPP)
    scene["background"] = [1.05, 1.05, 1.05]
    assert measure(scene)["z_excess"] > 6.0


def test_sphere_mask_is_the_disc_the_camera_sees():
    mask = sphere_mask(8)
    assert mask[4, 4] and mask[3, 3] and not mask[0, 0]
    assert (mask == mask[::-1]).all() and (mask == mask[:, ::-1]).all()
