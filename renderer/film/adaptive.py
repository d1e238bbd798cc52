"""Adaptive sampling: when a pixel, or a whole tile, has converged to the scene's target error.

The error measure is the relative MSE of a pixel's luminance, estimated from its sample buffer:

    e = Var[mean] / (mean² + ε),   ε = 0.01,

(the ε keeps black pixels from needing infinitely many samples; Rousselle et al. 2011 use the same
form). Two guards make it robust against the lucky pixel that saw the same value in all its first
samples (a caustic that no sample has hit yet has zero estimated variance):

- no pixel stops before ``MIN_SAMPLES`` samples;
- a pixel's variance is the largest over its 3×3 neighbourhood, so a zero-variance pixel in a
  noisy region keeps sampling with its neighbours.

``pixels_converged`` drives the local renderer; ``tile_converged`` is the farm's rule, a pure
function of a tile's merged sample buffer.
"""

from __future__ import annotations

import numpy as np

from renderer.film.buffer import SampleBuffer
from renderer.vecmath import LUMINANCE

EPSILON = 0.01
# Stopping on a pixel's own samples biases it low where its distribution is heavy-tailed (the
# rare bright path not seen yet): measured on examples/backlit_slab.json at target 0.02, the frame
# came out 3.8 % low with 16, 2.6 % with 32 and 1.4 % with 64 minimum samples; the Cornell box
# shows no bias at 64 (bench/adaptive.py, docs/adaptive-sampling.md).
MIN_SAMPLES = 64


def relative_error(buf: SampleBuffer, pooled: bool = True) -> np.ndarray:
    """Estimated relative MSE of every pixel's luminance, (h, w); inf where < MIN_SAMPLES.

    ``pooled``: use the 3×3 neighbourhood's largest variance (the stopping rule's guard); without
    it, each pixel's own estimate.
    """
    n = buf.count.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        lum_sum = buf.sum @ LUMINANCE
        # Σ Y² of the luminance Y = w·L needs cross terms the buffer does not keep; since the
        # weights sum to 1, (w·L)² ≤ Σ w_c L_c² (Cauchy–Schwarz): an upper bound, exact for grey
        # pixels, so the variance is never underestimated.
        lum_sq = buf.sum_sq @ LUMINANCE
        mean = lum_sum / n
        # Var[mean] = s²/n with s² = (Σ Y² − n·mean²)/(n − 1)
        var = np.maximum(lum_sq - n * mean * mean, 0.0) / ((n - 1) * n)
    var = np.where(n >= 2, var, np.inf)
    if pooled:
        # 3×3 neighbourhood maximum of the variance (edge pixels use what exists)
        padded = np.pad(var, 1, mode="edge")
        h, w = var.shape
        var = np.max(np.stack([padded[dy:dy + h, dx:dx + w] for dy in range(3)
                               for dx in range(3)]), axis=0)
    err = var / (np.nan_to_num(mean) ** 2 + EPSILON)
    return np.where(n >= MIN_SAMPLES, err, np.inf)


def pixels_converged(buf: SampleBuffer, target_error: float) -> np.ndarray:
    """(h, w) bool: pixels whose estimated relative MSE is at or below the target."""
    return relative_error(buf) <= target_error


def tile_converged(buf: SampleBuffer, target_error: float) -> bool:
    """The farm's rule: a tile is done when every one of its pixels has converged."""
    return bool(np.all(pixels_converged(buf, target_error)))
