"""bench.target_error's timing (``timed``): the best of ``repeat`` runs, and of more while they
have taken less than ``SHORT`` seconds in all, at most ``MOST_RUNS``; ``even`` reaches the render
(the loop's even variant, ``--even``)."""

from __future__ import annotations

import json
import time

import numpy as np

import bench.target_error as te
import renderer.render
from renderer.film.buffer import SampleBuffer


def _scene() -> dict:
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 4, "height": 3}
    scene["render"]["spp"] = 1
    return scene


def _fake(calls: list, seconds: float):
    def render_buffer(cs, even=False):
        calls.append(even)
        time.sleep(seconds)
        buf = SampleBuffer.empty(0, 0, cs.width, cs.height)
        buf.sum[:] = 1.0
        buf.count[:] = 2
        return buf

    return render_buffer


def test_a_frame_of_milliseconds_is_timed_as_often_as_the_cap_allows(monkeypatch):
    calls: list = []
    monkeypatch.setattr(renderer.render, "render_buffer", _fake(calls, 0.0))
    best, image, spp = te.timed(_scene(), 2, even=True)
    assert len(calls) == te.MOST_RUNS and all(calls)
    assert 0.0 < best < te.SHORT and spp == 2.0
    np.testing.assert_array_equal(image, 0.5)


def test_a_long_render_is_timed_repeat_times(monkeypatch):
    # (real renders; SHORT at 0 makes every run long enough)
    calls: list = []
    real = renderer.render.render_buffer

    def counting(cs, even=False):
        calls.append(even)
        return real(cs, even=even)

    monkeypatch.setattr(renderer.render, "render_buffer", counting)
    monkeypatch.setattr(te, "SHORT", 0.0)
    te.timed(_scene(), 3)
    assert calls == [False, False, False]


def test_runs_go_on_until_they_have_taken_the_short_time(monkeypatch):
    calls: list = []
    monkeypatch.setattr(renderer.render, "render_buffer", _fake(calls, te.SHORT / 2.5))
    te.timed(_scene(), 1)
    # 0.4, 0.8, 1.2 × SHORT: the third run is the first to reach it (a slow sleep only ends it
    # sooner)
    assert 2 <= len(calls) <= 3
