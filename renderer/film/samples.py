"""One sample into a tile's sample buffer, as the batched kernels add them."""

from __future__ import annotations

import math

from renderer.jit import inline_kernel


@inline_kernel
def add_sample(out_sum, out_sum_sq, out_count, out_dropped, row, col, r, g, b):
    """Add the radiance (r, g, b) of one sample to pixel (row, col) of the buffer's arrays
    (``SampleBuffer``'s sum, sum_sq, count, dropped); a sample that is not finite, or whose
    square overflows, is not added but counted in ``out_dropped``, as the scalar kernel does
    (``renderer.integrators.path.render_rows``), so the variance sums stay finite."""
    if math.isfinite(r * r) and math.isfinite(g * g) and math.isfinite(b * b):
        out_sum[row, col, 0] += r
        out_sum[row, col, 1] += g
        out_sum[row, col, 2] += b
        out_sum_sq[row, col, 0] += r * r
        out_sum_sq[row, col, 1] += g * g
        out_sum_sq[row, col, 2] += b * b
        out_count[row, col] += 1
    else:
        out_dropped[row, col] += 1
