"""The planner: a frame cut into tiles, each tile's samples into passes, and the order they run in.

Tiles are numbered in row-major order (tile ``t`` covers columns ``(t % nx) * size`` ...); pass
``p`` of a tile renders samples ``[p * spp_per_pass, min(spp, (p + 1) * spp_per_pass))`` of every
pixel. Sample indices are global, so the passes of a tile add up to ``render_tile`` over
``[0, spp)`` and the farm's image equals ``lucent render`` of the same scene.

The order: pass 0 of every tile first (a whole, coarse preview early), then pass 1 of every tile,
...; within a pass, tiles nearest the centre of the frame first (where the subject usually is).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Plan:
    width: int
    height: int
    spp: int
    tile_size: int
    spp_per_pass: int

    @property
    def tiles_x(self) -> int:
        return -(-self.width // self.tile_size)

    @property
    def tiles_y(self) -> int:
        return -(-self.height // self.tile_size)

    @property
    def n_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    @property
    def n_passes(self) -> int:
        """Passes per tile (every tile has the same)."""
        return -(-self.spp // self.spp_per_pass)

    @property
    def n_tasks(self) -> int:
        return self.n_tiles * self.n_passes

    def tile_rect(self, tile: int) -> tuple[int, int, int, int]:
        """``(x0, y0, width, height)`` of a tile; edge tiles are cut to the frame."""
        if not 0 <= tile < self.n_tiles:
            raise IndexError(f"tile {tile} out of range (0..{self.n_tiles - 1})")
        x0 = (tile % self.tiles_x) * self.tile_size
        y0 = (tile // self.tiles_x) * self.tile_size
        return x0, y0, min(self.tile_size, self.width - x0), min(self.tile_size, self.height - y0)

    def sample_range(self, pass_index: int) -> tuple[int, int]:
        """``(sample_start, sample_count)`` of a pass."""
        if not 0 <= pass_index < self.n_passes:
            raise IndexError(f"pass {pass_index} out of range (0..{self.n_passes - 1})")
        start = pass_index * self.spp_per_pass
        return start, min(self.spp_per_pass, self.spp - start)

    def tiles_by_distance(self) -> list[int]:
        """Tile indices, nearest the frame's centre first (ties in row-major order)."""
        cx, cy = self.width / 2.0, self.height / 2.0

        def distance_sq(tile: int) -> float:
            x0, y0, w, h = self.tile_rect(tile)
            return (x0 + w / 2.0 - cx) ** 2 + (y0 + h / 2.0 - cy) ** 2

        return sorted(range(self.n_tiles), key=lambda t: (distance_sq(t), t))

    def order(self) -> list[tuple[int, int]]:
        """Every ``(tile, pass)`` in the order to enqueue them."""
        tiles = self.tiles_by_distance()
        return [(t, p) for p in range(self.n_passes) for t in tiles]


def celery_priority(job_priority: int) -> int:
    """Job priority 0–9 (9 most urgent) to a Celery-on-Redis priority (0 is served first)."""
    return 9 - max(0, min(9, job_priority))
