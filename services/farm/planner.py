"""The planner: a frame cut into tiles, each tile's samples into passes, and the order they run in.

Tiles are numbered in row-major order (tile ``t`` covers columns ``(t % nx) * size`` ...). A
tile's samples are cut into passes that grow: ``spp_per_pass`` samples in pass 0, then each pass
``pass_growth`` times as many as all before it, until a pass would exceed ``max_spp_per_pass``;
from there on every pass has ``max_spp_per_pass`` samples, the last cut to ``spp``. With growth
1 (8, 8, 16, 32, … samples) every pass halves the noise variance of the tile; with growth 2, a
new job's default (8, 16, 48, …), every pass divides it by three, in fewer passes. With
``max_spp_per_pass`` equal to ``spp_per_pass`` (or 0) the passes are all equal. Pass 0 stays small
for a fast first preview while long jobs run few, large tasks: a task's fixed cost (fetching the
scene, encoding and merging its buffer, the broker round trips: ~5-6 ms of wall clock,
docs/performance.md) is paid once per pass, not once per ``spp_per_pass`` samples. Pass ``p``
renders the global sample indices ``[start_p, start_p + count_p)`` of every pixel, so the passes
of a tile add up to ``render_tile`` over ``[0, spp)`` and the farm's image equals ``lucent
render`` of the same scene.

The order: pass 0 of every tile first (a whole, coarse preview early), then the other passes,
the largest first (ties in pass order), each of every tile; within a pass, tiles nearest the
centre of the frame first (where the subject usually is). The workers take the tasks in that
order, so the last tasks of a job are its smallest: when one process has run out of work, the
other finishes a small pass, not a large one (the tail of the job; with growth 2 and 64 spp the
passes run 8, 40, 16). A tile's passes add up in any order, and its image is the same.

A job of ``frames`` frames (``services.farm.frames``) numbers its tiles across them: tile ``t``
is tile ``t % tiles_per_frame`` of frame ``t // tiles_per_frame``, so that every per-tile key and
rule of the store holds for frames unchanged. Its order interleaves tiles x passes x frames: pass
0 of every tile of frame 0, then of frame 1, ..., then pass 1 of every frame: a coarse preview of
every frame comes before any frame is refined.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property


def frame_tiles_count(width: int, height: int, tile_size: int) -> int:
    """Tiles of a frame of ``width`` × ``height`` in tiles of ``tile_size`` (edge tiles cut):
    ``Plan.tiles_per_frame``, and the merge's, which reads the plan's fields from the job hash."""
    return -(-width // tile_size) * -(-height // tile_size)


@dataclass(frozen=True)
class Plan:
    width: int
    height: int
    spp: int
    tile_size: int
    spp_per_pass: int
    max_spp_per_pass: int = 0
    """The largest pass; 0 or anything up to ``spp_per_pass``: every pass ``spp_per_pass``."""
    frames: int = 1
    """Frames of the job (each ``width x height``, the same spp)."""
    pass_growth: int = 1
    """Each pass after the first: this many times the samples before it (at most the cap).
    1: the rule of jobs stored before the growth was a field, and of jobs with a target error
    (``services.farm.jobs.queue_job``)."""

    @property
    def pass_cap(self) -> int:
        """The largest pass allowed: ``max_spp_per_pass``, never below ``spp_per_pass``."""
        return max(1, self.spp_per_pass, self.max_spp_per_pass)

    @cached_property
    def passes(self) -> tuple[tuple[int, int], ...]:
        """``(sample_start, sample_count)`` of every pass of a tile, in order."""
        base = max(1, self.spp_per_pass)
        cap = self.pass_cap
        growth = max(1, self.pass_growth)
        out = []
        start = 0
        while start < self.spp:
            # pass 0: base; then growth x the samples so far (growth 1: pass 1 is base too, and
            # every later pass doubles the total); at most cap
            count = base if start == 0 else min(cap, growth * start)
            count = min(count, self.spp - start)
            out.append((start, count))
            start += count
        return tuple(out)

    @property
    def tiles_x(self) -> int:
        return -(-self.width // self.tile_size)

    @property
    def tiles_y(self) -> int:
        return -(-self.height // self.tile_size)

    @property
    def tiles_per_frame(self) -> int:
        return frame_tiles_count(self.width, self.height, self.tile_size)

    @property
    def n_tiles(self) -> int:
        """Tiles of the whole job, every frame's."""
        return self.tiles_per_frame * self.frames

    def frame_of(self, tile: int) -> int:
        return tile // self.tiles_per_frame

    def frame_tiles(self, frame: int) -> range:
        """The job's tile numbers of one frame."""
        return range(frame * self.tiles_per_frame, (frame + 1) * self.tiles_per_frame)

    @property
    def n_passes(self) -> int:
        """Passes per tile (every tile has the same)."""
        return len(self.passes)

    @property
    def n_tasks(self) -> int:
        return self.n_tiles * self.n_passes

    def tile_rect(self, tile: int) -> tuple[int, int, int, int]:
        """``(x0, y0, width, height)`` of a tile in its frame; edge tiles are cut to the
        frame."""
        if not 0 <= tile < self.n_tiles:
            raise IndexError(f"tile {tile} out of range (0..{self.n_tiles - 1})")
        tile %= self.tiles_per_frame
        x0 = (tile % self.tiles_x) * self.tile_size
        y0 = (tile // self.tiles_x) * self.tile_size
        return x0, y0, min(self.tile_size, self.width - x0), min(self.tile_size, self.height - y0)

    def sample_range(self, pass_index: int) -> tuple[int, int]:
        """``(sample_start, sample_count)`` of a pass."""
        if not 0 <= pass_index < self.n_passes:
            raise IndexError(f"pass {pass_index} out of range (0..{self.n_passes - 1})")
        return self.passes[pass_index]

    def tiles_by_distance(self) -> list[int]:
        """Tile indices of a frame, nearest its centre first (ties in row-major order)."""
        cx, cy = self.width / 2.0, self.height / 2.0

        def distance_sq(tile: int) -> float:
            x0, y0, w, h = self.tile_rect(tile)
            return (x0 + w / 2.0 - cx) ** 2 + (y0 + h / 2.0 - cy) ** 2

        return sorted(range(self.tiles_per_frame), key=lambda t: (distance_sq(t), t))

    def pass_order(self) -> list[int]:
        """The passes in the order they are queued: pass 0 (the preview), then the others
        largest first, ties in pass order."""
        return [0] + sorted(range(1, self.n_passes), key=lambda p: (-self.passes[p][1], p))

    def order(self) -> list[tuple[int, int]]:
        """Every ``(tile, pass)`` in the order to enqueue them: passes (``pass_order``), then
        frames, then tiles nearest the centre first."""
        tiles = self.tiles_by_distance()
        per = self.tiles_per_frame
        return [(f * per + t, p) for p in self.pass_order() for f in range(self.frames)
                for t in tiles]

    def frame_order(self, frame: int) -> list[tuple[int, int]]:
        """The ``(tile, pass)`` pairs of one frame, in ``order``'s order."""
        first = frame * self.tiles_per_frame
        return [(first + t, p) for p in self.pass_order() for t in self.tiles_by_distance()]


def chain_heads(todo: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Of ``(tile, pass)`` pairs, each tile's first pass, in the order given. A job with a target
    error queues only these: its passes of a tile run one after the other, each queuing the next
    once it has merged, and the first that finds the tile converged stops the tile
    (``worker.tasks``), so a converged tile costs one task, not one per pass planned."""
    first: dict[int, int] = {}
    for tile, pass_index in todo:
        first[tile] = min(pass_index, first.get(tile, pass_index))
    return [(tile, pass_index) for tile, pass_index in todo if first[tile] == pass_index]


# A job that names no tile size gets the farm's default (``LUCENT_DEFAULT_TILE_SIZE``) halved
# while its frame would have fewer than MIN_TILES tiles, down to SMALLEST_DEFAULT_TILE px: a small
# frame still gives every worker of a small farm tiles to render in its first pass.
MIN_TILES = 16
SMALLEST_DEFAULT_TILE = 16


def default_tile_size(width: int, height: int, preferred: int) -> int:
    """The tile edge for a ``width`` × ``height`` frame when the job names none: ``preferred``,
    halved while the frame has fewer than ``MIN_TILES`` tiles (never below
    ``SMALLEST_DEFAULT_TILE``, nor ``preferred`` itself when that is smaller)."""
    size = preferred
    while size // 2 >= SMALLEST_DEFAULT_TILE and (-(-width // size)) * (-(-height // size)) \
            < MIN_TILES:
        size //= 2
    return size


def celery_priority(job_priority: int) -> int:
    """Job priority 0–9 (9 most urgent) to a Celery-on-Redis priority (0 is served first)."""
    return 9 - max(0, min(9, job_priority))
