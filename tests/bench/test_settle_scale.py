"""bench.settle_scale runs end to end on a small plan: one row a frame count, both timings
positive, and no job settled while one of its tiles renders."""

from __future__ import annotations

from bench.settle_scale import measure


def test_the_settle_benchmark_times_both_scopes_on_a_small_plan():
    rows = measure([1, 3], (96, 64), 32, 1)
    assert [(r["frames"], r["tiles"]) for r in rows] == [(1, 6), (3, 18)]
    assert all(r["job_ms"] > 0 and r["frame_ms"] > 0 for r in rows)
