"""bench.target_error --radius: the shape of the counts from each window radius, priced against
the true variance as ``--oracle`` prices a shape."""

from __future__ import annotations

import json

import numpy as np
import pytest

import bench.target_error as te


def test_every_radius_is_priced_and_none_beats_the_best_shape(monkeypatch):
    """On a small Cornell box: a row per count, and every radius's price at least the best any
    shape can reach (Cauchy–Schwarz: mean(√(v c))² / (mean v · mean c) for the v and c it is
    priced with) and finite."""
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 16, "height": 12}
    reference = np.full((12, 16, 3), 0.5)
    monkeypatch.setattr(te, "scene_reference", lambda name, scene, material: reference)
    bounds = []
    real_timed = te.timed_cost

    def timed_cost(data, tile=8):
        per = real_timed(data, tile)
        bounds.append(per)
        return per

    monkeypatch.setattr(te, "timed_cost", timed_cost)
    rows = te.radius_table(["box"], {"box": (scene, None)}, spps=(16, 64), radii=(1, 2, 8),
                           seeds=(7,))
    assert [r["spp"] for r in rows] == [16, 64]
    for row in rows:
        for r in (1, 2, 8):
            assert np.isfinite(row[f"r{r}"]) and 0.0 < row[f"r{r}"] < 10.0
    # the bound, from the same 1024-spp render and timing the table priced with
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    truth = render_buffer(load_scene(te.scene_at(scene, None, 1024, None)))
    n = truth.count[..., None]
    mean = truth.sum / n
    v = np.mean((truth.sum_sq - n * mean * mean) / (n - 1) / (reference**2 + 0.01), axis=-1)
    c = truth.segments / truth.count * bounds[0]
    best = np.sqrt(v * c).mean() ** 2 / (v.mean() * c.mean())
    assert all(row[f"r{r}"] >= best - 1e-9 for row in rows for r in (1, 2, 8))
    # and one of them written out: the 17×17 window's shape at 16 spp, the time to an error
    # with n ∝ s over uniform sampling's, mean(c s)·mean(v / s) / (mean c · mean v)
    from renderer.film.adaptive import shape_estimates

    ev, ec = shape_estimates(load_scene_buffer(scene, 16), radius=8)
    s = np.sqrt(ev / ((ec - 1.0) * bounds[0]))
    price = (c * s).mean() * (v / s).mean() / (c.mean() * v.mean())
    assert rows[0]["r8"] == pytest.approx(price, rel=1e-12)


def load_scene_buffer(scene: dict, spp: int):
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    return render_buffer(load_scene(te.scene_at(scene, None, spp, None, 7)))
