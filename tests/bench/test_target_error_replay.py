"""bench.target_error --replay: the target loop run on draws from a stash of a scene's samples,
its cost counted instead of timed."""

from __future__ import annotations

import json

import numpy as np
import pytest

import bench.target_error as te


def test_a_pass_hands_each_pixel_its_next_draws():
    """Each pixel gets the next ``counts[p]`` of its draws (those the generator picked, in
    order): their sums, squares, segments and count; a pass past the draws is refused."""
    rng = np.random.default_rng(3)
    radiance = rng.random((5, 2, 3, 3)).astype(np.float32)
    segments = rng.integers(1, 9, size=(5, 2, 3)).astype(np.float32)
    replay = te.StashReplay(radiance, segments, np.random.default_rng(11), draws=6)
    pick = np.random.default_rng(11).integers(0, 5, size=(6, 2, 3))
    first = np.array([[1, 0, 2], [3, 1, 1]])
    second = np.array([[2, 1, 0], [3, 2, 5]])
    done = np.zeros((2, 3), np.int64)
    for counts in (first, second):
        buf = replay(0, counts)
        for y in range(2):
            for x in range(3):
                taken = pick[done[y, x]:done[y, x] + counts[y, x], y, x]
                values = radiance[taken, y, x].astype(np.float64)
                assert np.allclose(buf.sum[y, x], values.sum(axis=0))
                assert np.allclose(buf.sum_sq[y, x], (values * values).sum(axis=0))
                assert buf.segments[y, x] == segments[taken, y, x].sum()
        assert (buf.count == counts).all()
        done += counts
    with pytest.raises(ValueError, match="draws"):
        replay(0, np.ones((2, 3), np.int64))  # the pixel at (1, 2) has had its six


def test_draws_are_the_stash_as_a_distribution():
    """Two draws a pixel from a stash of four samples: the frame's relative error against the
    stash's mean is mean(v) / 2 in expectation, v the stash's population variance (draws with
    replacement are independent; without, it would be two thirds of that). 1024 pixels, 40
    runs: the mean's relative spread is about 2 %; tolerance 7 %."""
    rng = np.random.default_rng(5)
    radiance = rng.exponential(1.0, size=(4, 32, 32, 3)).astype(np.float32)
    segments = np.ones((4, 32, 32), np.float32)
    mean, v = te.stash_truth(radiance)
    errors = []
    for run in range(40):
        replay = te.StashReplay(radiance, segments, np.random.default_rng(run), draws=2)
        buf = replay(0, np.full((32, 32), 2, np.int64))
        x = buf.sum / 2.0
        errors.append(((x - mean) ** 2 / (mean * mean + 0.01)).mean())
    assert np.mean(errors) == pytest.approx(v.mean() / 2.0, rel=0.07)


def test_the_rows_of_a_small_scene(monkeypatch):
    """On a small Cornell box: a rule and an even row for each target; the even variant's
    counts are the same in every pixel, so its cost over uniform sampling's at equal error is
    the same whatever the cost a sample (path segments or seconds): mean spp × error / mean(v);
    and its counts are priced at no less than mean(v) / mean spp."""
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 16, "height": 12}
    rows = te.replay(["box"], {"box": (scene, None)}, targets=[0.1, 0.03], runs=2, samples=48,
                     draws=160)
    assert [(r["target"], r["mode"]) for r in rows] == [
        (0.1, "rule"), (0.1, "even"), (0.03, "rule"), (0.03, "even")]
    radiance, _ = te.stash(te.scene_at(scene, None, 48, None), 48)
    _, v = te.stash_truth(radiance)
    for row in rows:
        assert 0.0 < row["ratio"] < 3.0 and row["time_ratio"] > 0.0
        if row["mode"] == "even":
            assert row["segments_ratio"] == pytest.approx(row["time_ratio"], rel=1e-9)
            assert row["segments_ratio"] == pytest.approx(
                row["mean_spp"] * row["ratio"] * row["target"] / v.mean(), rel=1e-9)
            # priced at mean(v) / n a run, at least mean(v) / mean n (Jensen)
            assert row["priced_ratio"] * row["target"] >= v.mean() / row["mean_spp"] * (1 - 1e-9)
            rule = next(r for r in rows if r["target"] == row["target"] and r["mode"] == "rule")
            assert row["shape_gain"] == pytest.approx(rule["time_ratio"] / row["time_ratio"])
