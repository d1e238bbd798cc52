"""bench.target_error's measured cost map (``timed_cost``), which prices the oracle's shapes in
time: a figure a tile, every pixel of the tile the same, and the thread count left as found; and
the gain the rule's estimates predict (``predicted_gain``) against its closed form."""

from __future__ import annotations

import json

import numba
import numpy as np

from bench.target_error import ROOT, predicted_gain, timed_cost


def test_the_cost_map_has_one_positive_figure_a_tile_and_leaves_the_threads_as_found():
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 20, "height": 12}  # tiles of 8: 3 × 2, the last ones cut short
    scene["render"]["spp"] = 2
    threads = numba.get_num_threads()
    cost = timed_cost(scene)
    assert numba.get_num_threads() == threads
    assert cost.shape == (12, 20)
    assert np.isfinite(cost).all() and (cost > 0).all()
    for y0, y1 in ((0, 8), (8, 12)):
        for x0, x1 in ((0, 8), (8, 16), (16, 20)):
            block = cost[y0:y1, x0:x1]
            assert (block == block[0, 0]).all(), (y0, x0)
    # the six tiles were timed apart: not one figure spread over the frame
    assert len(np.unique(cost)) > 1


def test_the_predicted_gain_is_its_closed_form():
    rng = np.random.default_rng(5)
    c = rng.uniform(1.0, 9.0, (6, 8))
    # v ∝ c: every pixel's error costs the same, so no shape gains
    assert abs(predicted_gain(3.0 * c, c) - 1.0) < 1e-12
    # half the pixels 100× the variance at equal cost: (√1 + √100)²/4 / (101/2) = 121/202
    v = np.where(np.arange(8) < 4, 1.0, 100.0)[None, :].repeat(6, 0)
    assert abs(predicted_gain(v, np.ones((6, 8))) - 121 / 202) < 1e-12
    # never above 1
    assert predicted_gain(rng.exponential(1.0, (6, 8)), c) <= 1.0
