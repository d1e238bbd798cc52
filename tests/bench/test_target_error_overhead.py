"""bench.target_error --overhead: the target loop timed whole and in its passes, and its final
counts rendered in one pass; the rest of the loop's time is its bookkeeping."""

from __future__ import annotations

import json
import time

import bench.target_error as te
import renderer.render


def _scenes() -> dict:
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 12, "height": 8}
    return {"tiny": (scene, None)}


def test_the_passes_are_timed_apart_from_the_bookkeeping(monkeypatch):
    """A render_tile that sleeps 20 ms a call: the loop's passes hold those sleeps, its
    bookkeeping does not, the one-pass render takes one, and render_tile is the module's own
    again afterwards."""
    real = renderer.render.render_tile
    calls = [0]

    def slow(*args, **kwargs):
        calls[0] += 1
        time.sleep(0.02)
        return real(*args, **kwargs)

    monkeypatch.setattr(renderer.render, "render_tile", slow)
    rows = te.overhead(["tiny"], _scenes(), [0.002], runs=2)
    assert renderer.render.render_tile is slow
    assert [r["mode"] for r in rows] == ["rule", "even"]
    for row in rows:
        assert row["passes"] >= 2  # the pilot and at least one round at this target
        assert row["passes_ms"] >= 20 * row["passes"]
        assert 0 < row["book_ms"] < 20
        assert abs(row["loop_ms"] - row["passes_ms"] - row["book_ms"]) < 1e-9
        assert 20 <= row["one_pass_ms"] < 20 * row["passes"]
        assert row["structure"] == row["loop_ms"] / row["one_pass_ms"]
        assert row["mean_spp"] >= 8
    # per mode: a warm-up loop, then runs × (the loop's passes + one pass)
    assert calls[0] == sum(r["passes"] * 3 + 2 for r in rows)
