"""bench.target_error --paired: uniform sampling's samples a pixel at a given error
(``equal_error_spp``), and the target run and uniform sampling at its error timed in pairs, in
turns (``paired``)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import bench.target_error as te
import renderer.render
from renderer.film.buffer import SampleBuffer


@pytest.mark.parametrize("start", [1, 7, 40, 5000])
def test_uniform_samples_at_an_error_from_any_start(start):
    # relMSE c / n: n = c / error, whatever count the search starts from
    calls: list[int] = []

    def error_at(n: int) -> float:
        calls.append(n)
        return 0.6 / n

    assert te.equal_error_spp(error_at, 0.6 / 37.5, start) == pytest.approx(37.5)
    # (read at whole counts, the last next to the answer)
    assert all(isinstance(n, int) for n in calls) and abs(calls[-1] - 37.5) <= 1


def test_an_error_with_a_floor_is_solved_where_it_is_reached():
    # c / n + f (a reference's own noise, say): the fixed point n = c / (error − f), where the
    # 1/n law alone, read far from it, would be off by the floor's share
    c, f, error = 2.0, 0.002, 0.01
    n = te.equal_error_spp(lambda m: c / m + f, error, 8, steps=30)
    assert abs(n - c / (error - f)) <= 1.0
    # (one step from 8 is 20 % short of it)
    assert te.equal_error_spp(lambda m: c / m + f, error, 8, steps=1) < 0.85 * c / (error - f)


def test_pairs_time_the_loop_against_uniform_sampling_at_its_error_in_turns(monkeypatch):
    """A render whose relMSE is 1 / (its image's value): uniform sampling at n spp reaches 1/n;
    the target run, 10 samples a pixel in 10 ms, an error of 1/20.5, which uniform sampling
    reaches at 20.5 spp, between its renders at 20 (20 ms) and 21 (a slow count: 63 ms). Its
    time there is interpolated, 41.5 ms, so the loop takes 0.24 of it; the pairs alternate
    which side goes first."""
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 4, "height": 3}
    events: list[str] = []

    def render_buffer(cs, even=False):
        target = cs.target_error is not None
        n = 10 if target else cs.spp
        events.append("L" if target else "U")
        time.sleep(1e-3 * n * (3 if n % 2 and not target else 1))
        buf = SampleBuffer.empty(0, 0, cs.width, cs.height)
        buf.count[:] = n
        buf.sum[:] = n * (20.5 if target else n)
        return buf

    monkeypatch.setattr(renderer.render, "render_buffer", render_buffer)
    monkeypatch.setattr(te, "rel_mse", lambda image, ref: 1.0 / float(image.mean()))
    monkeypatch.setattr(te, "scene_reference", lambda *a, **k: np.ones((3, 4, 3)))
    monkeypatch.setattr(te, "SHORT", 0.0)
    [row] = te.paired(["tiny"], {"tiny": (scene, None)}, [0.1], pairs=4, seeds=1)
    assert row["mean_spp"] == 10 and row["rel_mse"] == pytest.approx(1 / 20.5)
    assert row["ratio"] == pytest.approx(10 / 20.5) and row["uniform_spp"] == pytest.approx(20.5)
    assert row["runs"] == 1 and row["pairs"] == 4
    assert 0.18 < row["time_ratio_min"] <= row["time_ratio"] <= row["time_ratio_max"] < 0.33
    assert 0.18 < row["time_ratio_best"] < 0.33
    # the timed pairs (after the loop's run for its error, the uniform search and the warm-ups),
    # uniform sampling at both counts: loop then uniform, then uniform then loop, …
    assert "".join(events)[-12:] == "LUUUULLUUUUL"
