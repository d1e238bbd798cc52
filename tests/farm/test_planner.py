"""The planner (``services/farm/planner.py``): tiles × passes that cover a frame and its samples
exactly once, in the order the farm queues them."""

from __future__ import annotations

import numpy as np
import pytest

from services.farm.planner import (
    MIN_TILES,
    Plan,
    celery_priority,
    chain_heads,
    default_tile_size,
)


@pytest.mark.parametrize(("width", "height", "preferred", "size"), [
    (320, 240, 64, 64),    # 5 x 4 = 20 tiles: the preferred size
    (1920, 1080, 64, 64),
    (160, 120, 64, 32),    # 3 x 2 at 64 px: halved to 5 x 4
    (64, 48, 64, 16),      # 1 tile at 64, 2 x 2 at 32, 4 x 3 at 16: the floor
    (8, 8, 64, 16),        # one tile whatever the size: the floor
    (320, 240, 32, 32),    # an operator's smaller default stays
    (64, 48, 8, 8),        # below the floor: as configured
])
def test_default_tile_size_halves_until_the_frame_has_tiles_for_a_farm(width, height, preferred,
                                                                       size):
    assert default_tile_size(width, height, preferred) == size
    tiles = Plan(width, height, 8, size, 8).tiles_per_frame
    # as large as allowed: twice the size would give too few tiles (unless it is the preference)
    if size < preferred:
        assert Plan(width, height, 8, 2 * size, 8).tiles_per_frame < MIN_TILES
    if size > 16 and size < preferred:
        assert tiles >= MIN_TILES


def test_plan_covers_the_frame_once_and_goes_centre_first():
    plan = Plan(width=50, height=30, spp=20, tile_size=16, spp_per_pass=8)
    cover = np.zeros((30, 50), int)
    for t in range(plan.n_tiles):
        x0, y0, w, h = plan.tile_rect(t)
        cover[y0:y0 + h, x0:x0 + w] += 1
    assert (cover == 1).all()
    assert [plan.sample_range(p) for p in range(plan.n_passes)] == [(0, 8), (8, 8), (16, 4)]
    order = plan.order()
    assert len(order) == len(set(order)) == plan.n_tasks
    # Pass 0 of every tile before any pass 1; the first tile is one of the central ones.
    assert {p for _, p in order[:plan.n_tiles]} == {0}
    x0, y0, w, h = plan.tile_rect(order[0][0])
    assert x0 <= 25 <= x0 + w and y0 <= 15 <= y0 + h
    assert celery_priority(9) == 0 and celery_priority(0) == 9


def test_passes_grow_from_the_first_to_the_largest_and_cover_every_sample():
    # 8, 8, then the samples so far (16, 32), then the largest (64) until spp
    plan = Plan(width=8, height=8, spp=1000, tile_size=8, spp_per_pass=8, max_spp_per_pass=64)
    assert plan.passes[:6] == ((0, 8), (8, 8), (16, 16), (32, 32), (64, 64), (128, 64))
    assert plan.passes[-1] == (960, 40)
    assert plan.n_passes == 19 and plan.n_tasks == 19
    for spp, first, largest in [(1000, 8, 64), (64, 8, 64), (17, 3, 5), (5, 8, 64), (1, 1, 1),
                                (300, 7, 7), (300, 7, 0), (4096, 1, 1000)]:
        p = Plan(width=8, height=8, spp=spp, tile_size=8, spp_per_pass=first,
                 max_spp_per_pass=largest)
        starts = [s for s, _ in p.passes]
        counts = [c for _, c in p.passes]
        # Contiguous, from 0 to spp, none empty, none above the larger of first and largest.
        assert starts == [0] + list(np.cumsum(counts)[:-1]), (spp, first, largest)
        assert sum(counts) == spp and min(counts) >= 1
        assert max(counts) <= max(first, largest)
        assert [p.sample_range(i) for i in range(p.n_passes)] == list(p.passes)
        # Each pass after the second doubles the samples so far, until it reaches the largest.
        for (start, count), nxt in zip(p.passes[1:], p.passes[2:], strict=False):
            assert nxt[1] == min(max(first, largest), start + count, spp - nxt[0])
    # Equal passes: largest 0 or equal to the first, the plan of before passes grew.
    assert Plan(8, 8, 20, 8, 8).passes == ((0, 8), (8, 8), (16, 4))
    assert Plan(8, 8, 20, 8, 8, 8).passes == Plan(8, 8, 20, 8, 8).passes
    with pytest.raises(IndexError):
        Plan(8, 8, 20, 8, 8).sample_range(3)


@pytest.mark.parametrize("growth", [2, 3])
def test_passes_grow_by_the_plans_growth_and_cover_every_sample(growth):
    """Growth g: pass 0 is the first pass, every later one g times the samples before it (the
    total grows (g + 1)-fold), at most the largest; contiguous from 0 to spp, none empty."""
    plan = Plan(8, 8, 1000, 8, 8, 64, pass_growth=2)
    assert [c for _, c in plan.passes][:5] == [8, 16, 48, 64, 64]
    assert Plan(8, 8, 64, 8, 8, 64, pass_growth=2).passes == ((0, 8), (8, 16), (24, 40))
    for spp, first, largest in [(1000, 8, 64), (64, 8, 64), (17, 3, 5), (5, 8, 64), (1, 1, 1),
                                (300, 7, 7), (300, 7, 0), (4096, 1, 1000), (65, 8, 64)]:
        p = Plan(8, 8, spp, 8, first, largest, pass_growth=growth)
        counts = [c for _, c in p.passes]
        assert [s for s, _ in p.passes] == [0] + list(np.cumsum(counts)[:-1])
        assert sum(counts) == spp and min(counts) >= 1 and max(counts) <= max(first, largest)
        assert counts[0] == min(first, spp)
        for start, count in p.passes[1:]:
            assert count == min(max(first, largest), growth * start, spp - start)
        # Never more passes than growth 1 gives
        assert p.n_passes <= Plan(8, 8, spp, 8, first, largest).n_passes


@pytest.mark.parametrize("growth", [1, 2])
def test_after_the_preview_the_largest_passes_go_first(growth):
    """Pass 0 of every tile first; then the other passes largest first (ties in pass order), so
    that a job ends on its smallest tasks, each pass of every tile, centre first."""
    plan = Plan(50, 30, 512, 16, 8, 64, pass_growth=growth)
    sizes = [plan.passes[p][1] for p in plan.pass_order()]
    assert sorted(plan.pass_order()) == list(range(plan.n_passes)) and plan.pass_order()[0] == 0
    assert sizes[1:] == sorted(sizes[1:], reverse=True) and sizes[-1] < sizes[1]
    assert Plan(8, 8, 64, 8, 8, 64, pass_growth=2).pass_order() == [0, 2, 1]  # 8, 40, 16
    order = plan.order()
    assert len(order) == len(set(order)) == plan.n_tasks
    tiles = plan.tiles_by_distance()
    assert order == [(t, p) for p in plan.pass_order() for t in tiles]


def test_chain_heads_keep_each_tiles_first_pass_in_order():
    plan = Plan(width=32, height=16, spp=24, tile_size=8, spp_per_pass=8)  # 8 tiles x 3 passes
    order = plan.order()
    assert chain_heads(order) == order[:plan.n_tiles]  # pass 0 of every tile, centre first
    todo = [tp for tp in order if tp not in {(order[0][0], 0), (order[1][0], 0), (order[1][0], 1)}]
    heads = chain_heads(todo)
    assert sorted(heads) == sorted([(order[0][0], 1), (order[1][0], 2)]
                                   + [(t, 0) for t, _ in order[2:plan.n_tiles]])
    assert heads == [tp for tp in todo if tp in set(heads)]  # in the order given
    assert chain_heads([]) == []
